"""Wrappers: one small file each. Stateful wrappers keep the inner state in `env_state`."""

from jaxnat.wrappers.autoreset import AutoResetWrapper
from jaxnat.wrappers.base import Wrapper
from jaxnat.wrappers.frame_stack import FrameStackWrapper
from jaxnat.wrappers.legacy import LegacyStepAPIWrapper
from jaxnat.wrappers.log import LogWrapper
from jaxnat.wrappers.noise_observation import NoiseObservationWrapper
from jaxnat.wrappers.vmap import VmapWrapper

__all__ = [
    "Wrapper",
    "AutoResetWrapper",
    "LogWrapper",
    "VmapWrapper",
    "FrameStackWrapper",
    "NoiseObservationWrapper",
    "LegacyStepAPIWrapper",
]
