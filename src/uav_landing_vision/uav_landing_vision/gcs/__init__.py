"""GCS bridge core: camera → ship → landing frames, landing cone and stages, MAVLink output."""

from .bridge import GcsBridge, TickResult
from .config import ConeConfig, GcsBridgeConfig, MavlinkConfig, config_from_parameters, load_config
from .frames import DeckGeometry, LandingPose, camera_to_landing
from .landing import LandingGuidance, Stage, StageMachine, cone_geometry

__all__ = [
    "ConeConfig",
    "DeckGeometry",
    "GcsBridge",
    "GcsBridgeConfig",
    "LandingGuidance",
    "LandingPose",
    "MavlinkConfig",
    "Stage",
    "StageMachine",
    "TickResult",
    "camera_to_landing",
    "config_from_parameters",
    "cone_geometry",
    "load_config",
]
