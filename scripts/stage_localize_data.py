"""Copy the data `Localize/Clutter-v0` is built from into one folder, for a machine without
Debian's opencv-doc and dataset-fashion-mnist (e.g. a GPU box reached by copying a folder).

    python scripts/stage_localize_data.py .data          # ~46 MB
    # there:
    JAXNAT_DATA_DIR=.data python bench/localize_throughput.py --backgrounds .data/backgrounds

Layout written: `<dest>/digits/digits.png`, `<dest>/fashion_mnist/*-ubyte.gz` (found by
`JAXNAT_DATA_DIR`), and `<dest>/backgrounds/` holding opencv-doc's default natural photos and
videos (pass it as `backgrounds=`). The content-hash split of `jaxnat.natural` depends only on
the files' bytes, so the scenes built there are the ones built here.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

from jaxnat import natural
from jaxnat.datasets import locate


def main(argv=None):
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        raise SystemExit(__doc__)
    dest = Path(args[0])
    groups = {
        "digits": list(locate.find("digits", "train").files),
        "fashion_mnist": [*locate.find("fashion_mnist", "train").files,
                          *locate.find("fashion_mnist", "test").files],
        "backgrounds": [*natural.default_image_paths(), *natural.default_video_paths()],
    }
    total = 0
    for folder, files in groups.items():
        (dest / folder).mkdir(parents=True, exist_ok=True)
        for path in files:
            shutil.copyfile(path, dest / folder / path.name)
            total += path.stat().st_size
    print(f"{dest}: {total / 1e6:.1f} MB")


if __name__ == "__main__":
    main()
