"""The KITTI labels of an image's fits: what ``label_2/<image id>.txt`` holds (pitch and roll dropped), made where
the image was fitted (:func:`toosicubix.pipeline.fitting.iter_fit_file`'s workers) or by the writer
(:func:`toosicubix.pipeline.batch.write_outputs`)."""

from __future__ import annotations

from toosicubix.camera import Camera
from toosicubix.formats import kitti
from toosicubix.formats.results import ImageResult, VehicleResult

__all__ = ["kitti_lines", "kitti_objects"]


def kitti_objects(image_result: ImageResult, camera: Camera | None = None
                  ) -> list[tuple[VehicleResult, kitti.KittiObject]]:
    """The KITTI label objects of an image's successful fits (pitch and roll dropped), each with its fit.
    ``camera``: the image's (its ``t_cam_rect`` moves the locations to camera 0); default: the result's own."""
    if camera is None:
        camera = Camera(K=image_result.K, t_cam_rect=image_result.t_cam_rect, image_size=image_result.image_size)
    return [(v, kitti.object_from_pose(
        v.kitti_type, v.R_cam_vehicle, v.t_cam_vehicle, v.dimensions, camera, v.box2d,
        truncated=0.0 if v.truncated is None else v.truncated, occluded=kitti.OCCLUSION_UNKNOWN,
        score=1.0 if v.confidence is None else v.confidence, heading=v.heading or "directed"))
        for v in image_result.vehicles if v.ok]


def kitti_lines(image_result: ImageResult, camera: Camera | None = None) -> list[str]:
    """The KITTI label lines of an image's successful fits (pitch and roll dropped), in the order of its vehicles."""
    return [kitti.format_label_line(obj) for _, obj in kitti_objects(image_result, camera)]
