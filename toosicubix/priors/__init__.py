"""Size priors: the bundled and user tables (:mod:`.table`), their robust estimation from ground truth
(:mod:`.estimation`), and the geometric median it rests on (:mod:`.geometric_median`)."""
