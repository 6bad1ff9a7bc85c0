"""Draw the gallery: a strip per env family, the agent's observation and the human view.

Random actions from fixed keys (seed 0), so a rerun on the same machine draws the same PNGs:

    python scripts/gallery.py [--out docs/gallery] [--families classify,localize,mujoco,atari]

About 3 minutes on a shared 2-core CPU (PixelMuJoCo's three MJX compiles 1.5-2.5 of them,
Localize's scenes most of the rest). One PNG per family under `--out` (`classify.png`,
`localize.png`, `pixel_mujoco.png`, `natural_atari.png`). Each row is one env, each column one step `t`; a panel's caption says
what the agent did. Rows whose data (or ale-py and its ROMs) are missing here are skipped
with the reason printed; a family with no row left writes no file.

- Classify (`Classify/Digits-v0`, `Classify/FashionMNIST-v0`): the observation as the agent
  sees it (pixels revealed so far, the window tinted red: `jaxnat.compat.frames.Frames`) above
  the human view (the whole image, the window tinted).
- Localize (`Localize/Clutter-v0`): the photo with the footprint tinted (the agent's
  observation, `Frames`), the goal named in the row's label.
- PixelMuJoCo (`PixelMuJoCo/HalfCheetah-v0`, `physics="fast"`): the human view (the chase
  camera, RGB, checker floor, `Frames` of the robot) above the agent's observation, the newest
  84x84 gray frame, with the checker, the natural-video and the noise floor (same key and
  actions, so the same physics in all three rows). MJX on a CPU compiles for minutes.
- Natural Atari (`NaturalAtari/Breakout-v0`): the agent's observation (newest 84x84 gray
  frame of the stack) with the natural-video background, above the same game (same seed and
  actions) with the black background ALE draws.

This is a script, not a module of the package: it is for the docs, needs matplotlib's Pillow,
and draws from data (opencv-doc, Fashion-MNIST, ale-py's ROMs) a user may not have.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

CELL = 112  # panel side in pixels
LABEL_W = 168  # the row labels' column
CAPTION_H = 14  # the caption line above each panel
TITLE_H = 22
MAX_BYTES = 300_000
FAMILIES = ("classify", "localize", "mujoco", "atari")
BACKGROUND = (255, 255, 255)
INK = (0, 0, 0)


# --- layout ------------------------------------------------------------------------------------

def _font(size: int):
    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: the fixed bitmap font
        return ImageFont.load_default()


def _panel(frame: np.ndarray, cell: int) -> Image.Image:
    """uint8 `[H, W, 3]` (or `[H, W]`) -> a `cell` x `cell` image (aspect kept, centred):
    nearest-neighbour up (pixels stay visible), Lanczos down."""
    frame = np.asarray(frame, np.uint8)
    if frame.ndim == 2:
        frame = np.repeat(frame[..., None], 3, axis=-1)
    image = Image.fromarray(frame)
    h, w = frame.shape[:2]
    scale = cell / max(h, w)
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    image = image.resize(size, Image.NEAREST if scale >= 1 else Image.LANCZOS)
    out = Image.new("RGB", (cell, cell), BACKGROUND)
    out.paste(image, ((cell - size[0]) // 2, (cell - size[1]) // 2))
    return out


def layout(rows, title: str = "", *, cell: int = CELL) -> np.ndarray:
    """The strip: `rows` is a list of `(label, panels)`, each panel `(caption, frame)` with
    `frame` a uint8 `[H, W, 3]` or `[H, W]` array (None: an empty cell). Returns uint8
    `[TITLE_H + len(rows) * (CAPTION_H + cell), LABEL_W + columns * cell, 3]`, where `columns` is
    the longest row's length (`TITLE_H` is 0 without a title)."""
    columns = max((len(panels) for _, panels in rows), default=0)
    top = TITLE_H if title else 0
    height = top + len(rows) * (CAPTION_H + cell)
    canvas = Image.new("RGB", (LABEL_W + columns * cell, height), BACKGROUND)
    draw = ImageDraw.Draw(canvas)
    small, big = _font(11), _font(14)
    if title:
        draw.text((4, 3), title, fill=INK, font=big)
    for r, (label, panels) in enumerate(rows):
        y = top + r * (CAPTION_H + cell)
        draw.multiline_text((4, y + CAPTION_H + 4), _wrap(label, 24), fill=INK, font=small, spacing=2)
        for c, (caption, frame) in enumerate(panels):
            x = LABEL_W + c * cell
            draw.text((x + 2, y + 1), caption, fill=INK, font=small)
            if frame is not None:
                canvas.paste(_panel(frame, cell - 4), (x + 2, y + CAPTION_H))
    return np.asarray(canvas)


def _wrap(text: str, width: int) -> str:
    lines = []
    for paragraph in text.split("\n"):
        line = ""
        for word in paragraph.split(" "):
            if line and len(line) + 1 + len(word) > width:
                lines.append(line)
                line = word
            else:
                line = f"{line} {word}" if line else word
        lines.append(line)
    return "\n".join(lines)


def save(image: np.ndarray, path: Path) -> int:
    """Write `image` as a PNG, palette-quantised (256 colours) when the full-colour file would
    be over `MAX_BYTES`. Returns the file's size in bytes."""
    path.parent.mkdir(parents=True, exist_ok=True)
    picture = Image.fromarray(image)
    picture.save(path, optimize=True)
    if path.stat().st_size > MAX_BYTES:
        picture.quantize(256, method=Image.Quantize.MEDIANCUT).save(path, optimize=True)
    return path.stat().st_size


# --- rollouts ----------------------------------------------------------------------------------

def rollout(env, params, key, steps: int, actions=None, policy=None):
    """`steps` random actions (or `actions[t]`, or `policy(key, state)`) from a reset, in one
    jitted scan. Returns
    `(obs, states, actions, rewards, done)` stacked over `steps + 1` observations (the reset's
    first) and `steps` transitions (the actions taken). `env` must not autoreset."""
    import jax

    reset_key, act_key, step_key = jax.random.split(key, 3)
    space = env.action_space(params)
    if actions is None:
        actions = jax.vmap(space.sample)(jax.random.split(act_key, steps))

    def body(carry, xs):
        obs, state = carry
        k, action = xs
        if policy is not None:
            k, policy_key = jax.random.split(k)
            action = policy(policy_key, state)
        obs, state, reward, terminated, truncated, _ = env.step(k, state, action, params)
        return (obs, state), (obs, state, action, reward, terminated | truncated)

    @jax.jit
    def run(reset_key, step_key, actions):
        obs0, state0 = env.reset(reset_key, params)
        _, (obs, states, actions, rewards, done) = jax.lax.scan(
            body, (obs0, state0), (jax.random.split(step_key, steps), actions))
        cat = lambda a, b: jax.numpy.concatenate([a[None], b])  # noqa: E731
        return (jax.tree.map(cat, obs0, obs), jax.tree.map(cat, state0, states), actions,
                rewards, done)

    obs, states, actions, rewards, done = run(reset_key, step_key, actions)
    return (jax.tree.map(np.asarray, obs), states, np.asarray(actions), np.asarray(rewards),
            np.asarray(done))


def _at(tree, t):
    import jax

    return jax.tree.map(lambda a: a[t], tree)


def _ended(done: np.ndarray, t: int) -> bool:
    """Whether the episode ended before observation `t` was drawn (after step `t - 1`)."""
    return bool(done[: max(0, t - 1)].any())


def _tint(image: np.ndarray, mask: np.ndarray) -> np.ndarray:
    from jaxnat.compat.frames import TINT

    rgb = np.asarray(image, np.uint8)
    if rgb.shape[-1] == 1:
        rgb = np.repeat(rgb, 3, axis=-1)
    blend = ((rgb.astype(np.uint16) + TINT) // 2).astype(np.uint8)
    return np.where(np.asarray(mask)[..., None] > 0, blend, rgb)


MOVES = ("up", "down", "left", "right")


def classify_rows(env_id: str, shown, *, seed: int = 0, **kwargs):
    """Two rows for a Classify env: the agent's observation, the human view."""
    import jax

    import jaxnat
    from jaxnat.compat.frames import Frames

    env, params = jaxnat.make(env_id, autoreset=False, **kwargs)
    num_classes = len(env.class_names)

    def wrong_guess(key, state):  # a random move and a random wrong label: the episode runs on
        move_key, label_key = jax.random.split(key)
        move = jax.random.randint(move_key, (), 0, 4)
        label = (state.label + jax.random.randint(label_key, (), 1, num_classes)) % num_classes
        return jax.numpy.stack([move, label]).astype(jax.numpy.int32)

    obs, states, actions, rewards, done = rollout(env, params, jax.random.key(seed), max(shown),
                                            policy=wrong_guess)
    frames = Frames(env, params, batched=True)
    channels = env.observation_space(params).shape[-1] - 2
    agent, human = [], []
    names = env.class_names
    label = names[int(states.label[0])]
    for t in shown:
        if _ended(done, t):
            agent.append(("(ended)", None))
            human.append(("", None))
            continue
        if t == 0:
            caption = "t=0 reset"
        else:
            move, guess = actions[t - 1]
            caption = f"t={t} {MOVES[move]}, '{names[guess]}'"
        agent.append((caption, frames(obs[t], None)))
        image = np.asarray(params.images[int(states.image_index[t])])
        human.append(("", _tint(image, obs[t][..., channels + 1])))
    short = env_id.split("/")[1]
    return [(f"{short}: agent's observation (revealed, window red)", agent),
            (f"{short}: human view, the whole image (a '{label}')", human)]


def localize_rows(shown, *, seed: int = 0, split: str = "train"):
    import jax

    import jaxnat
    from jaxnat.compat.frames import Frames

    env, params = jaxnat.make("Localize/Clutter-v0", split=split, autoreset=False)
    obs, states, actions, rewards, done = rollout(env, params, jax.random.key(seed), max(shown))
    frames = Frames(env, params, batched=True)
    panels = []
    for t in shown:
        if _ended(done, t):
            panels.append(("(found)", None))
            continue
        caption = "t=0 reset" if t == 0 else f"t={t} {MOVES[int(actions[t - 1])]}"
        caption += " +1" if t > 0 and rewards[t - 1] > 0 else ""
        panels.append((caption, frames(_at(obs, t), None)))
    goal = env.class_names[int(obs["goal"][0])]
    return [(f"Clutter ({split}): the agent's observation, footprint red; find '{goal}'", panels)]


def mujoco_rows(shown, *, seed: int = 0, floors=("checker", "video", "noise")):
    """The chase camera (human view) once, then the agent's newest gray frame per floor: the
    same key and actions, so the same physics in every row."""
    import jax

    import jaxnat
    from jaxnat.compat.frames import Frames
    from jaxnat.datasets import DatasetNotFoundError

    env_id = "PixelMuJoCo/HalfCheetah-v0"
    rows, actions = [], None
    for floor in floors:
        try:
            env, params = jaxnat.make(env_id, physics="fast", floor=floor, autoreset=False)
        except DatasetNotFoundError as error:  # floor="video" without opencv-doc's videos
            print(f"mujoco: skipped floor={floor!r}: {str(error).splitlines()[0]}")
            continue
        if actions is None:
            space = env.action_space(params)
            keys = jax.random.split(jax.random.key(seed + 1), max(shown))
            actions = jax.vmap(space.sample)(keys)
            camera, camera_params = jaxnat.make(env_id, physics="fast", observation="state",
                                                autoreset=False)
        obs, states, _, _, done = rollout(env, params, jax.random.key(seed), max(shown), actions)
        if not rows:
            chase = Frames(camera, camera_params)
            rows.append(("HalfCheetah: human view, chase camera (RGB, checker)",
                         [(f"t={t}", chase(None, _at(states, t))) for t in shown]))
        rows.append((f"agent's observation, floor='{floor}' (newest gray frame)",
                     [(f"t={t}", obs[t][..., -1]) for t in shown]))
    return rows


def atari_rows(shown, *, seed: int = 0):
    import ale_py.roms  # ImportError without ale-py: the row is skipped

    import jaxnat

    rom = ale_py.roms.get_rom_path("breakout")
    if rom is None or not Path(rom).is_file():
        raise FileNotFoundError(f"ale-py {ale_py.__version__} has no Breakout ROM here")

    rows = []
    rng = np.random.default_rng(seed)
    actions = None
    for background in ("video", "none"):
        env = jaxnat.make_vec("NaturalAtari/Breakout-v0", 1, background=background, split="train")
        if actions is None:
            actions = rng.integers(0, env.single_action_space.n, max(shown))
        frames = {}
        obs, _ = env.reset(seed=seed)
        frames[0] = obs[0, ..., -1]
        for t in range(1, max(shown) + 1):
            obs, *_ = env.step(np.array([actions[t - 1]]))
            frames[t] = obs[0, ..., -1]
        env.close()
        label = ("Breakout, background='video' (the agent's observation)" if background == "video"
                 else "the same game, background='none' (ALE's black)")
        rows.append((label, [(f"t={t}", frames[t]) for t in shown]))
    return rows


# --- main --------------------------------------------------------------------------------------

def _rows_or_reason(make_rows):
    """`(rows, None)`, or `([], reason)` when the data or a package is missing."""
    from jaxnat.datasets import DatasetNotFoundError

    try:
        return make_rows(), None
    except (DatasetNotFoundError, ImportError, FileNotFoundError) as error:
        return [], f"{type(error).__name__}: {str(error).splitlines()[0]}"


def family_rows(family: str):
    """`(title, file name, panel side, [(rows, reason)])` per family."""
    if family == "classify":
        shown = (0, 1, 2, 3, 5, 8, 12)
        return ("Classify: move a 7x7 window, guess the label (random moves, random wrong labels)", "classify.png", CELL, [
            _rows_or_reason(lambda: classify_rows("Classify/Digits-v0", shown, w=7)),
            _rows_or_reason(lambda: classify_rows("Classify/FashionMNIST-v0", shown, w=7))])
    if family == "localize":
        shown = (0, 1, 2, 4, 8)
        return ("Localize: move the footprint onto the goal class (random actions)", "localize.png", 176, [
            _rows_or_reason(lambda: localize_rows(shown, split="train")),
            _rows_or_reason(lambda: localize_rows(shown, split="test", seed=1))])
    if family == "mujoco":
        shown = (0, 4, 8, 12, 16, 20)
        return ("PixelMuJoCo HalfCheetah (physics='fast', random torques)", "pixel_mujoco.png", CELL, [
            _rows_or_reason(lambda: mujoco_rows(shown))])
    if family == "atari":
        shown = (0, 10, 20, 30, 40, 50)
        return ("Natural Atari Breakout (random actions)", "natural_atari.png", CELL, [
            _rows_or_reason(lambda: atari_rows(shown))])
    raise ValueError(f"unknown family {family!r}; one of {', '.join(FAMILIES)}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/gallery")
    parser.add_argument("--families", default=",".join(FAMILIES),
                        help=f"comma-separated, of {', '.join(FAMILIES)}")
    args = parser.parse_args(argv)
    for family in args.families.split(","):
        start = time.perf_counter()
        title, name, cell, parts = family_rows(family.strip())
        rows = []
        for part, reason in parts:
            rows += part
            if reason:
                print(f"{family}: skipped a row: {reason}")
        if not rows:
            print(f"{family}: nothing to draw, no file written")
            continue
        path = Path(args.out) / name
        size = save(layout(rows, title, cell=cell), path)
        print(f"{path}: {size / 1000:.0f} kB in {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
