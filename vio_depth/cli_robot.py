"""The robot side of the command line: bag inputs, Kalibr calibration, ROS / MCAP outputs, Rerun.

Flags of ``vio-depth run`` (docs/ros.md)::

    --image-topic T --imu-topic T --camera-info-topic T --pose-topic T   (ROS bags; "none" = unused)
    --pose-frame imu|camera --max-pose-gap S --max-clock-jump S           (ROS bags)
    --calib camchain.yaml --imu-calib imu.yaml                            (any input: Kalibr)
    --save-mcap --save-rosbag2 --ros-prefix /vio_depth                    (outputs: OUT/run.mcap, OUT/rosbag2/)
    --rerun [URL] --rerun-save run.rrd                                    (live view)

and ``vio-depth inspect BAG`` (topics, types, counts, rates, and what a run would use).
"""

from __future__ import annotations

import argparse
import importlib.util
from pathlib import Path

from vio_core.errors import InputError, MissingDependencyError, SettingsError

from .export.rosout import RosOutputSettings, RosRunWriter
from .io import BagSettings, Sequence, apply_calibration, open_bag, open_sequence, read_calibration
from .io.bag import POSE_FRAMES, detect_bag
from .io.bag_topics import format_inspection, inspect_bag
from .viz import RerunSink, viewer_executable

#: flags that only apply to ROS bags (argparse dest -> flag)
_BAG_FLAGS = {"image_topic": "--image-topic", "imu_topic": "--imu-topic", "camera_info_topic": "--camera-info-topic",
              "pose_topic": "--pose-topic", "pose_frame": "--pose-frame", "max_pose_gap": "--max-pose-gap",
              "max_clock_jump": "--max-clock-jump"}
#: name of the MCAP file and the ROS 2 bag folder in --out
MCAP_NAME = "run.mcap"
ROSBAG2_NAME = "rosbag2"


def add_input_flags(p: argparse.ArgumentParser) -> None:
    """Bag topic and Kalibr calibration flags (``run`` and ``inspect``)."""
    g = p.add_argument_group("ROS bags and calibration (docs/ros.md)")
    g.add_argument("--image-topic", default=None, metavar="TOPIC",
                   help="sensor_msgs/Image or CompressedImage topic (default: the only one in the bag)")
    g.add_argument("--imu-topic", default=None, metavar="TOPIC", help="sensor_msgs/Imu topic (default: the only one)")
    g.add_argument("--camera-info-topic", default=None, metavar="TOPIC",
                   help="sensor_msgs/CameraInfo topic (default: the one beside the image topic)")
    g.add_argument("--pose-topic", default=None, metavar="TOPIC",
                   help="ground-truth poses (PoseStamped, PoseWithCovarianceStamped, TransformStamped, Odometry; "
                        "default: the only one; none: no poses)")
    g.add_argument("--pose-frame", default=None, choices=POSE_FRAMES,
                   help="what the pose topic describes: imu (default, as EuRoC's ground truth) or camera")
    g.add_argument("--max-pose-gap", type=float, default=None, metavar="S",
                   help="a frame takes a pose between two samples at most S apart (default 0.1)")
    g.add_argument("--max-clock-jump", type=float, default=None, metavar="S",
                   help="largest change of header stamp minus bag time between messages (default 1.0)")
    g.add_argument("--calib", default=None, metavar="CAMCHAIN",
                   help="Kalibr camchain.yaml: intrinsics, distortion, T_cam_imu, timeshift_cam_imu (any input)")
    g.add_argument("--imu-calib", default=None, metavar="IMU_YAML",
                   help="Kalibr imu.yaml: IMU noise densities and random walks (any input with an IMU)")


def add_output_flags(p: argparse.ArgumentParser) -> None:
    """ROS / MCAP output and Rerun flags of ``run``."""
    g = p.add_argument_group("robot tools (docs/ros.md)")
    g.add_argument("--save-mcap", action="store_true",
                   help=f"also write OUT/{MCAP_NAME}: depth (32FC1 and 16UC1), sigma, camera info, points, poses "
                        "and tf, for Foxglove / ROS 2")
    g.add_argument("--save-rosbag2", action="store_true",
                   help=f"also write the same messages as a ROS 2 SQLite3 bag OUT/{ROSBAG2_NAME}/")
    g.add_argument("--ros-prefix", default=None, metavar="PREFIX",
                   help="topic namespace of those outputs (default /vio_depth)")
    g.add_argument("--rerun", nargs="?", const="", default=None, metavar="URL",
                   help="live view in Rerun: spawn a viewer, or connect to the one at URL (needs '.[viz]')")
    g.add_argument("--rerun-save", default=None, metavar="FILE.rrd", help="write the Rerun recording to FILE.rrd")


def add_inspect_parser(sub) -> None:
    p = sub.add_parser("inspect", help="list a ROS bag's topics, types, counts and rates, and what a run would use")
    p.add_argument("bag", help="ROS 1 .bag, ROS 2 bag folder or .mcap file")
    add_input_flags(p)


def bag_settings(args) -> BagSettings:
    """The bag flags (and ``--calib`` / ``--imu-calib``) as :class:`BagSettings`."""
    calibration = read_calibration(args.calib, args.imu_calib, args.image_topic)
    given = {k: v for k, v in (("image_topic", args.image_topic), ("imu_topic", args.imu_topic),
                               ("camera_info_topic", args.camera_info_topic), ("pose_topic", args.pose_topic),
                               ("pose_frame", args.pose_frame), ("max_pose_gap_s", args.max_pose_gap),
                               ("max_clock_jump_s", args.max_clock_jump)) if v is not None}
    return BagSettings(calibration=calibration, **given)


def open_input(args) -> Sequence:
    """The run's sequence: a bag with the bag flags, else the folder with ``--calib`` applied.

    Raises:
        SettingsError: a bag flag for an input that is not a bag.
    """
    if (args.format == "rosbag") or (args.format is None and detect_bag(args.sequence)):
        return open_bag(args.sequence, bag_settings(args))
    used = [flag for dest, flag in _BAG_FLAGS.items() if getattr(args, dest) is not None]
    if used:
        raise SettingsError(f"{', '.join(used)} appl{'ies' if len(used) == 1 else 'y'} to ROS bags only; "
                            f"{args.sequence} is not one")
    sequence = open_sequence(args.sequence, format=args.format)
    if args.calib or args.imu_calib:
        sequence = apply_calibration(sequence, read_calibration(args.calib, args.imu_calib))
    return sequence


def input_paths(args) -> list:
    """Calibration files a run reads (``--out`` may not touch them)."""
    return [p for p in (args.calib, args.imu_calib) if p]


def sink_factories(args) -> list:
    """The frame sinks the flags ask for (:mod:`vio_depth.run.sinks`). A Rerun view is checked
    (the package, the viewer) when the run starts."""
    settings = RosOutputSettings() if args.ros_prefix is None else RosOutputSettings(prefix=args.ros_prefix)
    if args.ros_prefix is not None and not (args.save_mcap or args.save_rosbag2):
        raise SettingsError("--ros-prefix applies to --save-mcap / --save-rosbag2")
    out = []
    if args.save_mcap:
        out.append(lambda staging: RosRunWriter(staging / MCAP_NAME, "mcap", settings))
    if args.save_rosbag2:
        out.append(lambda staging: RosRunWriter(staging / ROSBAG2_NAME, "rosbag2", settings))
    if args.rerun and "://" not in args.rerun:
        raise SettingsError(f"--rerun {args.rerun!r}: expected a viewer URL such as rerun+http://127.0.0.1:9876/proxy "
                            "(--rerun alone spawns a viewer; put it after the sequence)")
    if args.rerun is not None or args.rerun_save:
        if importlib.util.find_spec("rerun") is None:
            raise MissingDependencyError("rerun-sdk", "viz", "the Rerun view (--rerun, --rerun-save)")
        if args.rerun == "" and viewer_executable() is None:
            raise MissingDependencyError("rerun-sdk", "viz", "spawning a Rerun viewer (--rerun; no `rerun` executable "
                                         "found; or give --rerun URL of a running viewer)")
        if args.rerun_save and not Path(args.rerun_save).resolve().parent.is_dir():
            raise InputError(f"--rerun-save {args.rerun_save}: its folder does not exist")
        view = dict(spawn=args.rerun == "", connect=args.rerun or None, save=args.rerun_save)
        out.append(lambda staging: RerunSink(**view))
    return out


def written_outputs(args) -> list[str]:
    """Lines naming the robot outputs a finished run wrote."""
    names = [f"{args.out}/{MCAP_NAME}" if args.save_mcap else "",
             f"{args.out}/{ROSBAG2_NAME}/" if args.save_rosbag2 else "", args.rerun_save or ""]
    names = [n for n in names if n]
    return [f"robot outputs: {', '.join(names)} (docs/ros.md)"] if names else []


def cmd_inspect(args) -> int:
    print(format_inspection(inspect_bag(args.bag, bag_settings(args))))
    return 0


__all__ = ["add_input_flags", "add_inspect_parser", "add_output_flags", "bag_settings", "cmd_inspect", "input_paths",
           "open_input", "sink_factories", "written_outputs"]
