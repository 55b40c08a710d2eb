"""A simulated annotator on real ground-truth cuboids (:mod:`.annotator`): the clicks of the benchmarks, and on
tracks the 2D box a person draws around each frame's vehicle (:mod:`.boxes`)."""
