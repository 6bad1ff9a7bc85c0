"""Draw example observations of `Localize/Clutter-v0` for the docs (docs/img/localize_clutter.png).

Top row: the observation's photo with the footprint channel outlined (the agent starts in the
centre) and the goal it is given; bottom row: the scene's class map (grey = void).

    python scripts/localize_examples.py [--out docs/img/localize_clutter.png]
"""

from __future__ import annotations

import argparse

import jax
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import jaxnat  # noqa: E402
from jaxnat.datasets.segmentation import VOID  # noqa: E402


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/img/localize_clutter.png")
    parser.add_argument("--per-split", type=int, default=2)
    args = parser.parse_args(argv)
    shots = []
    for split in ("train", "test"):
        env, params = jaxnat.make("Localize/Clutter-v0", split=split, autoreset=False)
        for i in range(args.per_split):
            obs, state = env.reset(jax.random.key(10 + i), params)
            shots.append((split, env.class_names, np.asarray(obs["pixels"]), int(obs["goal"]),
                          np.asarray(params.class_maps[state.image_index])))
    palette = plt.get_cmap("tab20")(np.arange(20))[:, :3]
    fig, axes = plt.subplots(2, len(shots), figsize=(2.3 * len(shots), 5.0), dpi=80)
    for col, (split, names, pixels, goal, class_map) in enumerate(shots):
        top, bottom = axes[0, col], axes[1, col]
        top.imshow(pixels[..., :3])
        top.contour(pixels[..., 3] > 0, levels=[0.5], colors="white", linewidths=1.5)
        top.set_title(f"{split}: find '{names[goal]}'", fontsize=9)
        colours = np.where((class_map == VOID)[..., None], 0.5,
                           palette[np.minimum(class_map, 19)])
        bottom.imshow(colours)
        bottom.contour(class_map == goal, levels=[0.5], colors="black", linewidths=1)
        bottom.set_title("class map (goal outlined)", fontsize=8)
        for ax in (top, bottom):
            ax.set_xticks([])
            ax.set_yticks([])
    fig.tight_layout()
    fig.savefig(args.out)
    print(args.out)


if __name__ == "__main__":
    main()
