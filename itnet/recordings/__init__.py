"""Robot recordings: ROS 1 and ROS 2 bags (sqlite3, MCAP; RealSense recordings are ROS 1 bags)
in, each frame's answer with its header out, as JSON lines, as ``vision_msgs/Detection3DArray``
messages in a bag, and as a Rerun log to look at. See docs/recordings.md.

    from itnet.recordings import Selection, scene_answers
    for item in scene_answers(Path("recording.bag"), Selection(every=3), find):
        ...

Needs the ``recordings`` extra (``pip install 'itnet[recordings]'``: rosbags, rerun-sdk).
"""

from itnet.recordings.answer import SceneAnswer, describe, pose_answers, scene_answers
from itnet.recordings.bag import (
    Frame,
    FrameError,
    Recording,
    RecordingError,
    Selection,
    is_recording,
    open_recording,
)
from itnet.recordings.bag_writer import Answer, write_answers
from itnet.recordings.ros_answer import detection_array, poses_stamped

__all__ = [
    "Answer",
    "Frame",
    "FrameError",
    "Recording",
    "RecordingError",
    "SceneAnswer",
    "Selection",
    "describe",
    "detection_array",
    "is_recording",
    "open_recording",
    "pose_answers",
    "poses_stamped",
    "scene_answers",
    "write_answers",
]
