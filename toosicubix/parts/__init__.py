"""The parts a person clicks and the linear model ``X_i = A_i p`` of their 3D points (:mod:`.linear`), and its
forward model, clicks rendered from a known cuboid (:mod:`.synthesis`)."""
