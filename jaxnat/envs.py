"""The registered env ids. Entry points are strings, so nothing heavy is imported here."""

from jaxnat.registration import register

_CLASSIFY = "jaxnat.vision_envs.classify:Classify"
for _name, _dataset in [
    ("MNIST", "mnist"),
    ("FashionMNIST", "fashion_mnist"),
    ("Digits", "digits"),
    ("CIFAR10", "cifar10"),
    ("CIFAR100", "cifar100"),
    ("ImageFolder", "image_folder"),
]:
    register(f"Classify/{_name}-v0", _CLASSIFY, dataset=_dataset)

_LOCALIZE = "jaxnat.vision_envs.localize:Localize"
register("Localize/Cityscapes-v0", _LOCALIZE, dataset="cityscapes")
register("Localize/Clutter-v0", _LOCALIZE, dataset="clutter")

# Natural Atari: every game ALE ships, emulated in batches on the host (jaxnat.make_vec only).
from jaxnat.atari.games import GAMES as _ATARI_GAMES  # noqa: E402  (plain data, no ale-py)

for _game in _ATARI_GAMES:
    register(
        f"NaturalAtari/{_game}-v0",
        "jaxnat.atari.env:NaturalAtariVecEnv",
        extra="atari",
        batched=True,
        game=_game,
    )
# MuJoCo robots in MJX with Gymnasium v5 semantics, state observations (jaxnat[mujoco]).
for _name, _module in [
    ("Ant", "ant"),
    ("HalfCheetah", "half_cheetah"),
    ("Hopper", "hopper"),
    ("Swimmer", "swimmer"),
]:
    register(f"MuJoCo/{_name}-v0", f"jaxnat.mjx_pixel.{_module}:{_name}", extra="mujoco")

# The same robots seen through the tracking camera: pixels (pure-JAX ray caster), a checker,
# natural-video or noise floor, or a pure-noise, state or constant observation (jaxnat[mujoco]).
for _name, _robot in [
    ("Ant", "ant"),
    ("HalfCheetah", "half_cheetah"),
    ("Hopper", "hopper"),
    ("Swimmer", "swimmer"),
]:
    register(f"PixelMuJoCo/{_name}-v0", "jaxnat.mjx_pixel.pixel:PixelMuJoCo", extra="mujoco",
             robot=_robot)
