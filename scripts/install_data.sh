#!/usr/bin/env bash
# Install the embedded default data: Debian's opencv-doc (5,000 MNIST digits in digits.png and
# natural videos/photos) and dataset-fashion-mnist (official IDX files). Idempotent: does nothing
# when the files are already there. Never fails the build: without root or apt it says what to do.
set -u
DIGITS=/usr/share/doc/opencv-doc/examples/data/digits.png
FASHION=/usr/share/datasets/fashion-mnist/t10k-labels-idx1-ubyte.gz
missing=()
[ -f "$DIGITS" ] || missing+=(opencv-doc)
[ -f "$FASHION" ] || missing+=(dataset-fashion-mnist)
# OSMesa: off-screen OpenGL for mujoco.Renderer, the reference the PixelMuJoCo renderer is
# tested against on CPU machines (MUJOCO_GL=osmesa).
ldconfig -p 2>/dev/null | grep -q libOSMesa || missing+=(libosmesa6)
[ ${#missing[@]} -eq 0 ] && exit 0

if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
  echo "jaxnat: installing data packages: ${missing[*]}"
  export DEBIAN_FRONTEND=noninteractive
  if apt-get install -y -q --no-install-recommends "${missing[@]}" >/tmp/jaxnat-apt.log 2>&1 \
     || { apt-get update -q >>/tmp/jaxnat-apt.log 2>&1 \
          && apt-get install -y -q --no-install-recommends "${missing[@]}" >>/tmp/jaxnat-apt.log 2>&1; }; then
    exit 0
  fi
  echo "jaxnat: apt-get could not install ${missing[*]} (log: /tmp/jaxnat-apt.log)." >&2
else
  echo "jaxnat: the embedded datasets are missing (${missing[*]})." >&2
fi
cat >&2 <<MSG
  On Debian/Ubuntu:  sudo apt-get install ${missing[*]}
  Elsewhere: put the files in a directory and point JAXNAT_DATA_DIR at it, e.g.
    \$JAXNAT_DATA_DIR/digits/digits.png   (OpenCV's samples/data/digits.png)
    \$JAXNAT_DATA_DIR/fashion_mnist/{train,t10k}-{images-idx3,labels-idx1}-ubyte.gz
  or download with: python -c "import jaxnat.datasets as d; d.download('fashion_mnist')"
  Tests that need these files are skipped without them.
MSG
exit 0
