"""Readers and writers of files other tools use: KITTI labels and calibration, Cityscapes 3D, ApolloCar3D, COCO,
CVAT, Label Studio, OpenLABEL, cameras, results JSON; one folder walker per dataset (:mod:`.datasets`)."""
