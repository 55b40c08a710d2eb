"""The parts a person clicks, as geometry: the linear model ``X_i = A_i p`` of their 3D points, one linear form per
kind (:mod:`.linear`), its forward model, clicks rendered from a known cuboid (:mod:`.synthesis`), the flat keypoint
names of the labelling tools (:mod:`.keypoints`) and keypoint positions learned from data (:mod:`.learned`). The
vocabulary they draw on (every kind and name with its clicks, faces, typical position and the prototypes it suits)
is :mod:`toosicubix.vocabulary`, data in ``toosicubix/vocabulary.json``."""
