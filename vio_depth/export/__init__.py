"""Optional outputs of a run: float depth ``.npy``, colourised previews, PLY point clouds, thumbnails,
and the results as ROS messages (:mod:`.rosout`: an MCAP file or a ROS 2 bag).

Pure writers (``write_depth_npy``, ``depth_preview`` / ``error_preview``, ``sparse_cloud`` /
``dense_cloud`` + ``write_ply``) and the :class:`RunExporter` that a run drives frame by
frame (:mod:`.exporter` lists the files). Lower layers never import this package.
"""

from .colormap import available_colormaps, colormap_lut, depth_from_rgb, depth_to_index, index_to_depth, nearest_index
from .exporter import ExportReport, RunExporter, legend_json, resize_to_width
from .npy import depth_as_float32, read_depth_npy, write_depth_npy
from .ply import VERTEX_DTYPE, PointCloud, dense_cloud, encode_ply, sparse_cloud, write_ply
from .preview import (
                       PreviewSettings,
                       depth_percentiles,
                       depth_preview,
                       error_preview,
                       parse_depth_range,
                       read_png_rgb,
                       relative_error,
                       run_depth_range,
                       write_jpeg_rgb,
                       write_png_rgb,
)
from .rosout import ROS_OUTPUT_KINDS, RosOutputSettings, RosRunWriter, frame_stamp_ns
from .selection import FrameSelection, has_depth, select_frames
from .settings import ExportSettings, PlySettings, parse_frame_list, parse_ply_spec

__all__ = [
    "ExportReport", "ExportSettings", "FrameSelection", "PlySettings", "PointCloud", "PreviewSettings",
    "ROS_OUTPUT_KINDS", "RosOutputSettings", "RosRunWriter", "RunExporter", "VERTEX_DTYPE", "available_colormaps", "colormap_lut", "dense_cloud", "depth_as_float32",
    "depth_from_rgb", "depth_percentiles", "depth_preview", "depth_to_index", "encode_ply", "error_preview",
    "frame_stamp_ns",
    "has_depth", "index_to_depth", "legend_json", "nearest_index", "parse_depth_range", "parse_frame_list",
    "parse_ply_spec", "read_depth_npy", "read_png_rgb", "relative_error", "resize_to_width",
    "run_depth_range", "select_frames", "sparse_cloud", "write_depth_npy", "write_jpeg_rgb", "write_ply",
    "write_png_rgb",
]
