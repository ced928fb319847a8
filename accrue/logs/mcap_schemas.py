"""JSON schemas of the messages in accrue's episode MCAP files.

Foxglove's well-known schemas are written in their JSON encoding (Foxglove reads them by schema
name, so poses and images show up in its 3D and image panels without any plugin); accrue's own
messages get small `accrue.*` schemas so plots and the raw-message panel can name every field.
"""

from __future__ import annotations

_TIME = {
    "type": "object",
    "properties": {"sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0}},
}
_VECTOR3 = {
    "type": "object",
    "properties": {k: {"type": "number"} for k in ("x", "y", "z")},
}
_QUATERNION = {
    "type": "object",
    "properties": {k: {"type": "number"} for k in ("x", "y", "z", "w")},
}
_NUMBERS = {"type": "array", "items": {"type": "number"}}

FOXGLOVE_POSE_IN_FRAME = {
    "title": "foxglove.PoseInFrame",
    "description": "A timestamped pose for an object or reference frame in 3D space",
    "type": "object",
    "properties": {
        "timestamp": _TIME,
        "frame_id": {"type": "string"},
        "pose": {
            "type": "object",
            "properties": {"position": _VECTOR3, "orientation": _QUATERNION},
        },
    },
}

FOXGLOVE_COMPRESSED_IMAGE = {
    "title": "foxglove.CompressedImage",
    "description": "A compressed image",
    "type": "object",
    "properties": {
        "timestamp": _TIME,
        "frame_id": {"type": "string"},
        "data": {"type": "string", "contentEncoding": "base64"},
        "format": {"type": "string", "description": "jpeg, png or webp"},
    },
}

ACCRUE_STATE = {
    "title": "accrue.State",
    "description": "The flat state observation the policy saw (names in the channel metadata)",
    "type": "object",
    "properties": {"t": {"type": "integer"}, "values": _NUMBERS},
}

ACCRUE_WRENCH = {
    "title": "accrue.Wrench",
    "description": "Wrist force (N) and torque (N m)",
    "type": "object",
    "properties": {"t": {"type": "integer"}, "force": _VECTOR3, "torque": _VECTOR3},
}

ACCRUE_ACTION = {
    "title": "accrue.Action",
    "description": "The executed action, normalised to [-1, 1] (the 6-D end-effector delta in the simulator; a robot's d action keys)",
    "type": "object",
    "properties": {"t": {"type": "integer"}, "action": _NUMBERS},
}

ACCRUE_REFERENCE_CHUNK = {
    "title": "accrue.ReferenceChunk",
    "description": "The base policy's reference action chunk (H x d) the learner refined",
    "type": "object",
    "properties": {
        "t": {"type": "integer"},
        "horizon": {"type": "integer"},
        "chunk": {"type": "array", "items": _NUMBERS},
    },
}

ACCRUE_REWARD = {
    "title": "accrue.Reward",
    "description": "Per-step reward and the undiscounted return so far",
    "type": "object",
    "properties": {"t": {"type": "integer"}, "reward": {"type": "number"}, "return": {"type": "number"}},
}

ACCRUE_EPISODE_LABEL = {
    "title": "accrue.EpisodeLabel",
    "description": "How the episode ended",
    "type": "object",
    "properties": {
        "success": {"type": "boolean"},
        "length": {"type": "integer"},
        "return": {"type": "number"},
        "truncated": {"type": "boolean"},
    },
}
