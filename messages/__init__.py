"""touch4d.messages: one class per topic type, each declared once (messages/base.py); msgpack on the
wire with numpy arrays kept intact; the header every message carries in messages/header.py.

See docs/contracts.md for the table of topics and fields.
"""
from .base import Message, MessageError, TYPES, decode, decoder, encode
from .hand import ControllerState, HandJoints, HandPose, HandPoses
from .physics import PhysicsContacts, PhysicsInput
from .scene import PHYSICS_COMMANDS, PROJECTIONS, SCENE_COMMANDS, SLICE_TOUCH, VIEWS, SceneCommand, SceneState
from .study import STUDY_COMMANDS, STUDY_PHASES, StudyCommand, StudyResponse, StudyTrial
from .system import Heartbeat, InputEvents, MotorStatus, MotorTrace, Stop
from .tactile import MotorCommand, MotorCommands, TactileField

TOPIC_TYPES: dict[str, type[Message]] = {
    "hand/pose": HandPose,
    "hand/poses": HandPoses,
    "hand/joints": HandJoints,
    "hand/joints/other": HandJoints,
    "controller/state": ControllerState,
    "scene/state": SceneState,
    "scene/command": SceneCommand,
    "tactile/field": TactileField,
    "tactile/motors": MotorCommand,
    "tactile/played": MotorCommands,
    "motors/status": MotorStatus,
    "motors/trace": MotorTrace,
    "safety/stop": Stop,
    "node/heartbeat": Heartbeat,
    "ui/input": InputEvents,
    "study/trial": StudyTrial,
    "study/response": StudyResponse,
    "study/command": StudyCommand,
    "physics/contacts": PhysicsContacts,
    "physics/journal": PhysicsInput,
}

__all__ = [
    "Message", "MessageError", "TYPES", "TOPIC_TYPES", "encode", "decode", "decoder",
    "HandPose", "HandPoses", "HandJoints", "ControllerState", "SceneState", "SceneCommand", "TactileField", "MotorCommand", "MotorCommands",
    "MotorStatus", "MotorTrace", "Stop", "Heartbeat", "InputEvents", "PHYSICS_COMMANDS", "PROJECTIONS", "SCENE_COMMANDS",
    "VIEWS", "SLICE_TOUCH",
    "StudyTrial", "StudyResponse", "StudyCommand", "STUDY_PHASES", "STUDY_COMMANDS",
    "PhysicsContacts", "PhysicsInput",
]
