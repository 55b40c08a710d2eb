"""A simulated annotator on real ground-truth cuboids (:mod:`.annotator`): the clicks of the benchmarks."""
