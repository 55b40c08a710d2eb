"""Jobs over whole annotation files: fit a batch and write its outputs (:mod:`.batch`), check it without writing
(:mod:`.validation`), choose the prior weights (:mod:`.tuning`)."""
