"""Geometry for the zone checks: polygons, camera models, person cylinders, tool pose, ISO/TS 15066.

Pure functions over numpy arrays; nothing here reads files or keeps state.

Frames and units:

* image: pixels of one camera at its full resolution, x right, y down, origin at the top-left
  corner of the top-left pixel (``*_px``);
* cell: metres, z up, origin at the robot base on the floor (``*_m``);
* camera: OpenCV convention, x right, y down, z forward; ``x_cam = R @ x_cell + t``.

Python-fcl does the 3-D overlap and distance tests; the helpers that build its objects are here so
that tests can check them against closed-form distances.

One module per job: ``poses`` (rotations, tool pose), ``polygons``, ``camera`` (homography,
camera models, horizon), ``distortion`` (is a lens model one-to-one over
the image), ``separation`` (ISO/TS 15066 arithmetic, reaction time), ``shapes`` (FCL
objects), ``calibration`` (tracker-to-flange and tracker-to-cell calibration, AX = XB).

Also here: placement of a box on the floor with occluders, shadows and floor regions
(``occlusion``), box algebra: IoU, NMS and merging (``boxes``), and the reaction-time budget
measured (``reaction``). May import: the bottom layer only (``types``, ``schema``, ``errors``).
"""

from monitor.geometry.calibration import (
    ToolCalibration,
    calibrate_tool,
    matrix_to_rpy_deg,
    rotation_angle_deg,
)
from monitor.geometry.camera import (
    CameraModel,
    apply_homography,
    fit_homography,
    look_at,
    reprojection_errors_px,
)
from monitor.geometry.distortion import distortion_fault
from monitor.geometry.errors import GeometryError
from monitor.geometry.polygons import (
    PolygonEdges,
    clip_polygon_to_rect,
    is_convex,
    points_in_polygon,
    points_in_polygons,
    polygon_fault,
    polygon_signed_area,
    triangulate_polygon,
)
from monitor.geometry.poses import (
    ToolPose,
    matrix_to_quaternion_xyzw,
    pose_in_frame,
    quaternion_to_matrix,
    rigid,
    rpy_to_matrix,
    tool_transform,
)
from monitor.geometry.separation import (
    DEFAULT_REACTION_TIME_S,
    WHOLE_BODY_INTRUSION_M,
    PersonModel,
    ReactionBudget,
    SeparationParams,
    describe_separation,
    intrusion_distance_m,
    max_robot_speed_mps,
    protective_separation_m,
    reaction_time_s,
    separation_speed_scale,
)
from monitor.geometry.shapes import (
    fcl_box,
    fcl_mesh,
    fcl_prism_parts,
    fcl_vertical_cylinder,
    points_in_mesh,
)

__all__ = [
    "DEFAULT_REACTION_TIME_S",
    "WHOLE_BODY_INTRUSION_M",
    "CameraModel",
    "GeometryError",
    "PersonModel",
    "PolygonEdges",
    "ReactionBudget",
    "SeparationParams",
    "ToolCalibration",
    "ToolPose",
    "apply_homography",
    "calibrate_tool",
    "clip_polygon_to_rect",
    "describe_separation",
    "distortion_fault",
    "fcl_box",
    "fcl_mesh",
    "fcl_prism_parts",
    "fcl_vertical_cylinder",
    "fit_homography",
    "intrusion_distance_m",
    "is_convex",
    "look_at",
    "matrix_to_quaternion_xyzw",
    "matrix_to_rpy_deg",
    "max_robot_speed_mps",
    "points_in_mesh",
    "points_in_polygon",
    "points_in_polygons",
    "polygon_fault",
    "polygon_signed_area",
    "pose_in_frame",
    "protective_separation_m",
    "quaternion_to_matrix",
    "reaction_time_s",
    "reprojection_errors_px",
    "rigid",
    "rotation_angle_deg",
    "rpy_to_matrix",
    "separation_speed_scale",
    "tool_transform",
    "triangulate_polygon",
]
