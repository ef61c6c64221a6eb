"""Recordings edited the way real ones go wrong, for the tests of the commands that read them."""

from pathlib import Path


def record_frame_twice(bag: Path, out: Path, frame: int = 1) -> list[int]:
    """``bag`` copied to ``out`` with every message of ``frame`` (by bag time) recorded once more,
    1 ns later, as a recorder that got a frame twice; the original bag times."""
    from rosbags.rosbag2 import Reader, Writer
    from rosbags.typesys import Stores, get_typestore

    with Reader(bag) as reader, Writer(out, version=9) as writer:
        typestore = get_typestore(Stores.ROS2_JAZZY)
        conns = {c.id: writer.add_connection(c.topic, c.msgtype, typestore=typestore) for c in reader.connections}
        messages = list(reader.messages())
        stamps = sorted({t for _, t, _ in messages})
        for conn, t_ns, raw in messages:
            writer.write(conns[conn.id], t_ns, raw)
            if t_ns == stamps[frame]:
                writer.write(conns[conn.id], t_ns + 1, raw)
    return stamps


def rename_topics(bag: Path, out: Path, names: dict) -> None:
    """``bag`` copied to ``out`` with its topics renamed by ``names`` ``{old: new}``, as a recording
    made with another camera driver's topic names."""
    from rosbags.rosbag2 import Reader, Writer
    from rosbags.typesys import Stores, get_typestore

    with Reader(bag) as reader, Writer(out, version=9) as writer:
        typestore = get_typestore(Stores.ROS2_JAZZY)
        conns = {c.id: writer.add_connection(names.get(c.topic, c.topic), c.msgtype, typestore=typestore)
                 for c in reader.connections}
        for conn, t_ns, raw in reader.messages():
            writer.write(conns[conn.id], t_ns, raw)


def drop_messages(bag: Path, out: Path, topic: str) -> None:
    """``bag`` copied to ``out`` without the messages of ``topic`` (its connection kept), as a
    recording during which that driver sent nothing."""
    from rosbags.rosbag2 import Reader, Writer
    from rosbags.typesys import Stores, get_typestore

    with Reader(bag) as reader, Writer(out, version=9) as writer:
        typestore = get_typestore(Stores.ROS2_JAZZY)
        conns = {c.id: writer.add_connection(c.topic, c.msgtype, typestore=typestore) for c in reader.connections}
        for conn, t_ns, raw in reader.messages():
            if conn.topic != topic:
                writer.write(conns[conn.id], t_ns, raw)
