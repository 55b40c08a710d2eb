"""The parts a person clicks: the one part vocabulary (:mod:`.vocabulary`, data in ``vocabulary.json``: every kind
and name with its clicks, faces, typical position and the prototypes it suits), the linear model ``X_i = A_i p`` of
their 3D points, one linear form per kind (:mod:`.linear`), and its forward model, clicks rendered from a known
cuboid (:mod:`.synthesis`)."""
