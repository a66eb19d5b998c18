"""Opening a bag, its topic catalogue, and which topics a run uses (``vio-depth inspect BAG``).

:func:`open_reader` opens any bag ``rosbags`` reads (ROS 1 ``.bag``; ROS 2 folder with
``metadata.yaml``, SQLite3 or MCAP storage; bare ``.mcap`` / ``.db3`` files) and turns the
library's exceptions into one-line :class:`~vio_core.errors.InputError` s;
:func:`choose_topics` resolves the topic flags against the catalogue (a topic not given is
the only one of its type, or none); :func:`inspect_bag` / :func:`format_inspection` are the
``inspect`` command.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from vio_core.errors import InputError

from .bag_messages import CAMERA_INFO, IMAGE_TYPES, IMU, POSE_TYPES

#: flag value that switches an optional topic off
NO_TOPIC = "none"
_ROLES = {"image": IMAGE_TYPES, "imu": (IMU,), "camera_info": (CAMERA_INFO,), "pose": POSE_TYPES}
_FLAGS = {"image": "--image-topic", "imu": "--imu-topic", "camera_info": "--camera-info-topic",
          "pose": "--pose-topic"}


def reader_error(path, exc: BaseException) -> InputError:
    """One line for an exception of the bag libraries (damaged or truncated bag, bad definitions)."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    kind = bag_kind(Path(path))
    hint = {"ROS 1 bag": "`rosbag reindex` repairs a bag cut short", "MCAP file": "`mcap recover` repairs a file "
            "cut short"}.get(kind, "a damaged SQLite3 file can be salvaged with `sqlite3 FILE .recover`"
                                   if "sqlite3" in kind else "`mcap recover` repairs an MCAP file cut short")
    return InputError(f"{path}: cannot read the {kind} ({type(exc).__name__}: {text}); is it complete? {hint}")


def bag_kind(path: Path) -> str:
    """What the bag is: ``ROS 1 bag``, ``ROS 2 bag (sqlite3|mcap)`` or ``MCAP file``."""
    if path.is_dir():
        return "ROS 2 bag (mcap)" if any(path.glob("*.mcap")) else "ROS 2 bag (sqlite3)"
    return {".bag": "ROS 1 bag", ".mcap": "MCAP file", ".db3": "ROS 2 bag (sqlite3)"}.get(path.suffix, "bag")


def open_reader(path) -> tuple[AnyReader, str]:
    """An opened ``rosbags`` reader of ``path`` and the bag's kind.

    Raises:
        InputError: missing path, not a bag, a damaged or truncated bag (one line).
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file or directory")
    if path.is_file():
        with open(path, "rb") as fh:
            magic = fh.read(8)
        if not magic:
            raise InputError(f"{path}: empty file (not a bag)")
        for prefix, suffix, what in ((b"#ROSBAG", ".bag", "a ROS 1 bag"), (b"\x89MCAP", ".mcap", "an MCAP file"),
                                     (b"SQLite f", ".db3", "a SQLite3 database")):
            if magic.startswith(prefix) and path.suffix != suffix:
                raise InputError(f"{path}: {what}, but not named *{suffix} (the readers go by the name)")
    try:
        # ROS 2 bags may carry no message definitions (older rosbag2): the standard ones are then used
        reader = AnyReader([path], default_typestore=get_typestore(Stores.LATEST))
        reader.open()
    except Exception as exc:
        raise reader_error(path, exc) from None
    return reader, bag_kind(path)


@dataclass(frozen=True)
class TopicInfo:
    """One topic of a bag: name, message type (``sensor_msgs/msg/Image``), message count and,
    when measured (:func:`inspect_bag`), the bag times of its first and last message (ns)."""

    name: str
    msgtype: str
    count: int
    first_ns: int | None = None
    last_ns: int | None = None

    @property
    def rate_hz(self) -> float | None:
        """Mean message rate over the topic's own span, or None (unmeasured, or fewer than 2 messages)."""
        if self.first_ns is None or self.last_ns is None or self.count < 2 or self.last_ns <= self.first_ns:
            return None
        return (self.count - 1) / ((self.last_ns - self.first_ns) / 1e9)


@dataclass(frozen=True)
class BagTopics:
    """The topics of an open bag and its time span (bag clock, nanoseconds)."""

    topics: tuple[TopicInfo, ...]
    start_ns: int
    end_ns: int

    @classmethod
    def of(cls, reader: AnyReader) -> "BagTopics":
        infos = tuple(TopicInfo(name, info.msgtype or "(mixed types)", int(info.msgcount))
                      for name, info in sorted(reader.topics.items()))
        count = sum(t.count for t in infos)
        return cls(infos, int(reader.start_time) if count else 0, int(reader.end_time) if count else 0)

    @property
    def duration_s(self) -> float:
        return max(0.0, (self.end_ns - self.start_ns) / 1e9)

    def by_name(self, name: str) -> TopicInfo | None:
        return next((t for t in self.topics if t.name == name), None)

    def of_types(self, types) -> list[TopicInfo]:
        return [t for t in self.topics if t.msgtype in types and t.count > 0]

    @staticmethod
    def connections(reader: AnyReader, topic: str) -> list:
        return [c for c in reader.connections if c.topic == topic]


@dataclass(frozen=True)
class TopicChoice:
    """The topics a run reads (None: not used) and how each was chosen (``notes``)."""

    image: str
    imu: str | None = None
    camera_info: str | None = None
    pose: str | None = None
    notes: tuple[str, ...] = ()


def _pick(catalogue: BagTopics, role: str, given: str | None, path, required: bool, prefer: str = "") -> str | None:
    types = _ROLES[role]
    flag = _FLAGS[role]
    if given is not None and given.lower() == NO_TOPIC:
        if required:
            raise InputError(f"{path}: {flag} cannot be none")
        return None
    if given is not None:
        info = catalogue.by_name(given)
        if info is None:
            have = ", ".join(f"{t.name} ({t.msgtype})" for t in catalogue.of_types(types)) or "none"
            raise InputError(f"{path}: no topic {given} ({flag}); topics of a fitting type: {have}")
        if info.msgtype not in types:
            raise InputError(f"{path}: {given} carries {info.msgtype}, but {flag} needs {' or '.join(types)}")
        if info.count == 0:
            raise InputError(f"{path}: no message on {given} ({flag})")
        return given
    candidates = catalogue.of_types(types)
    if prefer:
        near = [t for t in candidates if t.name.rsplit("/", 1)[0] == prefer]
        candidates = near if len(near) == 1 else candidates
    if len(candidates) == 1:
        return candidates[0].name
    if not candidates:
        if required:
            all_topics = ", ".join(f"{t.name} ({t.msgtype})" for t in catalogue.topics) or "none: an empty bag"
            raise InputError(f"{path}: no image topic (sensor_msgs/Image or CompressedImage); topics: {all_topics}")
        return None
    names = ", ".join(t.name for t in candidates)
    what = role.replace("_", " ")
    raise InputError(f"{path}: several topics could serve as {what} ({names}): choose one with {flag}")


def choose_topics(catalogue: BagTopics, settings, path) -> TopicChoice:
    """The topics of ``settings`` (a :class:`~vio_depth.io.bag.BagSettings`) resolved against the bag.

    Raises:
        InputError: an empty bag, a named topic that is missing, empty or of the wrong type, or
            an unnamed role with several candidates (all listed).
    """
    if not catalogue.topics or all(t.count == 0 for t in catalogue.topics):
        raise InputError(f"{path}: the bag holds no message (empty or truncated)")
    notes = []
    image = _pick(catalogue, "image", settings.image_topic, path, True)
    namespace = image.rsplit("/", 1)[0]
    chosen = {"image": image}
    for role, given in (("imu", settings.imu_topic), ("camera_info", settings.camera_info_topic),
                        ("pose", settings.pose_topic)):
        chosen[role] = _pick(catalogue, role, given, path, False, namespace if role == "camera_info" else "")
        if given is None and chosen[role] is not None:
            notes.append(f"{role.replace('_', ' ')}: {chosen[role]} (the only one; {_FLAGS[role]} to change)")
    if settings.image_topic is None:
        notes.insert(0, f"image: {image} (the only one; --image-topic to change)")
    return TopicChoice(image, chosen["imu"], chosen["camera_info"], chosen["pose"], tuple(notes))


# --------------------------------------------------------------------------- inspect
@dataclass(frozen=True)
class BagInspection:
    """What ``vio-depth inspect`` prints: the bag, its topics, and what a run would use (or why not)."""

    path: Path
    kind: str
    catalogue: BagTopics
    choice: TopicChoice | None
    problem: str = ""
    needs: tuple[str, ...] = ()


def inspect_bag(path, settings) -> BagInspection:
    """The topics of the bag at ``path`` (with each topic's time span, from one pass over the
    messages without decoding them) and the choice ``settings`` (a ``BagSettings``) leads to."""
    path = Path(path)
    reader, kind = open_reader(path)
    try:
        catalogue = BagTopics.of(reader)
        first: dict[str, int] = {}
        last: dict[str, int] = {}
        for conn, t, _ in reader.messages():
            first.setdefault(conn.topic, t)
            last[conn.topic] = t
    except InputError:
        raise
    except Exception as exc:
        raise reader_error(path, exc) from None
    finally:
        reader.close()
    catalogue = BagTopics(tuple(TopicInfo(t.name, t.msgtype, t.count, first.get(t.name), last.get(t.name))
                                for t in catalogue.topics), catalogue.start_ns, catalogue.end_ns)
    try:
        choice, problem = choose_topics(catalogue, settings, path), ""
    except InputError as exc:
        choice, problem = None, str(exc).removeprefix(f"{path}: ")
    return BagInspection(path, kind, catalogue, choice, problem, _needs(choice, settings))


def _needs(choice: TopicChoice | None, settings) -> tuple[str, ...]:
    """What a run on ``choice`` still needs from the command line (calibration files)."""
    if choice is None:
        return ()
    calib = settings.calibration
    extrinsic = calib.camera is not None and calib.camera.T_c_i is not None
    out = []
    if calib.camera is not None:
        out.append(f"(uses) the camera of --calib ({calib.camera.name}{', T_cam_imu' if extrinsic else ''})"
                   + (f" instead of {choice.camera_info}" if choice.camera_info else ""))
    if calib.imu is not None:
        out.append("(uses) the IMU noise model of --imu-calib")
    if not choice.camera_info and calib.camera is None:
        out.append("the camera: --calib camchain.yaml (no CameraInfo topic)")
    if choice.imu and not (extrinsic and calib.imu is not None):
        out.append("for --poses imu / vio: --calib camchain.yaml with T_cam_imu and --imu-calib imu.yaml")
    if choice.pose and settings.pose_frame == "imu" and not extrinsic:
        out.append(f"for the poses of {choice.pose} (IMU frame): --calib camchain.yaml with T_cam_imu, or "
                   "--pose-frame camera, or --pose-topic none")
    return tuple(out)


def format_inspection(info: BagInspection) -> str:
    """The inspection as a table (rates over each topic's own span, bag clock)."""
    cat = info.catalogue
    lines = [f"{info.path}: {info.kind}, {sum(t.count for t in cat.topics)} messages, {cat.duration_s:.2f} s "
             f"(bag clock {cat.start_ns} .. {cat.end_ns} ns)", ""]
    width = max([len(t.name) for t in cat.topics] + [5])
    type_width = max([len(t.msgtype) for t in cat.topics] + [4])
    lines.append(f"  {'topic':{width}s}  {'type':{type_width}s}  {'count':>7s}  {'rate':>10s}  use")
    roles = {} if info.choice is None else {v: k for k, v in (("image", info.choice.image), ("imu", info.choice.imu),
                                                               ("camera info", info.choice.camera_info),
                                                               ("poses (gt)", info.choice.pose)) if v}
    for t in cat.topics:
        rate = f"{t.rate_hz:7.1f} Hz" if t.rate_hz is not None else f"{'-':>10s}"
        lines.append(f"  {t.name:{width}s}  {t.msgtype:{type_width}s}  {t.count:7d}  {rate}  {roles.get(t.name, '')}")
    lines.append("")
    if info.choice is None:
        lines.append(f"a run would fail: {info.problem}")
    else:
        lines += [f"a run would use: {note}" for note in info.choice.notes]
        missing = [name for name, v in (("IMU", info.choice.imu), ("camera info", info.choice.camera_info),
                                        ("poses", info.choice.pose)) if not v]
        if missing:
            lines.append("not in the bag (or not chosen): " + ", ".join(missing))
        lines += [f"a run would use {n.removeprefix('(uses) ')}" if n.startswith("(uses) ") else f"a run needs {n}"
                  for n in info.needs]
    return "\n".join(lines)


__all__ = ["BagInspection", "BagTopics", "NO_TOPIC", "TopicChoice", "TopicInfo", "bag_kind", "choose_topics",
           "format_inspection", "inspect_bag", "open_reader", "reader_error"]
