"""Natural Atari: ALE games whose black background shows natural video, noise or photos.

Emulated on the host by ale-py's C++ vector env, composited and resized in one numba pass
(bit-identical to OpenCV's INTER_AREA), then the standard Atari preprocessing
(docs/environments.md section 3). Needs the `atari` extra (ale-py, numba).
"""

from jaxnat.atari.games import AUTHORS_GAMES, GAMES, RomNotFoundError

__all__ = ["AUTHORS_GAMES", "GAMES", "RomNotFoundError", "NaturalAtariVecEnv"]


def __getattr__(name):  # the env imports ale-py: only when asked for
    if name == "NaturalAtariVecEnv":
        from jaxnat.atari.env import NaturalAtariVecEnv

        return NaturalAtariVecEnv
    raise AttributeError(f"module 'jaxnat.atari' has no attribute {name!r}")
