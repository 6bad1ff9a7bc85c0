"""Download a dataset's official files, verified by checksum, into the folder `load` searches.

    download("mnist")     -> $JAXNAT_DATA_DIR/mnist (or ~/.cache/jaxnat/data/mnist), 4 IDX .gz files
    download("cifar10")   -> ...; cifar-10-binary.tar.gz, unpacked to cifar-10-batches-bin/

Sources: MNIST from the ossci-datasets S3 mirror that torchvision uses (LeCun's site no longer
serves the files reliably), Fashion-MNIST from Zalando's S3 bucket, CIFAR-10/100 binary releases
from the University of Toronto. Every file is pinned by SHA-256, so plain-http sources are safe.
"digits" comes with the opencv-doc Debian package and "image_folder" is your own data; neither is
downloadable.

Each file is streamed to `<dest>/<file>.part`, its hash checked, and only then renamed into place
(os.replace, atomic), so `<dest>/<file>` is either absent or complete and verified. Any error
(network failure, short response, hash mismatch) deletes the .part and raises `DownloadError`.
A .part left behind by an interrupted process (Ctrl-C, kill) is resumed with an HTTP Range
request; if the server ignores the Range the download restarts from zero.

Tarballs are unpacked into a temporary folder inside `dest` and moved into place, refusing any
member that is not a plain file or folder or whose path is absolute or contains "..". The
tarball is kept, so a second `download` only re-verifies it.
"""

from __future__ import annotations

import dataclasses
import hashlib
import http.client
import os
import re
import shutil
import tarfile
import tempfile
import urllib.request
from pathlib import Path, PurePosixPath

from jaxnat.datasets.base import DatasetFormatError
from jaxnat.datasets.locate import default_download_dir

__all__ = ["Remote", "REMOTES", "DownloadError", "download"]


class DownloadError(OSError):
    """A download failed or did not match its checksum; nothing was left at the target path."""


@dataclasses.dataclass(frozen=True)
class Remote:
    url: str
    sha256: str


_MNIST = "https://ossci-datasets.s3.amazonaws.com/mnist/"
_FASHION = "http://fashion-mnist.s3-website.eu-central-1.amazonaws.com/"
_CIFAR = "https://www.cs.toronto.edu/~kriz/"

# SHA-256 of the official files (the same values are published by TensorFlow Datasets' checksum
# registry and several independent projects; they match the md5s on the publishers' pages).
REMOTES: dict[str, dict[str, Remote]] = {
    "mnist": {
        "train-images-idx3-ubyte.gz": Remote(
            _MNIST + "train-images-idx3-ubyte.gz",
            "440fcabf73cc546fa21475e81ea370265605f56be210a4024d2ca8f203523609"),
        "train-labels-idx1-ubyte.gz": Remote(
            _MNIST + "train-labels-idx1-ubyte.gz",
            "3552534a0a558bbed6aed32b30c495cca23d567ec52cac8be1a0730e8010255c"),
        "t10k-images-idx3-ubyte.gz": Remote(
            _MNIST + "t10k-images-idx3-ubyte.gz",
            "8d422c7b0a1c1c79245a5bcf07fe86e33eeafee792b84584aec276f5a2dbc4e6"),
        "t10k-labels-idx1-ubyte.gz": Remote(
            _MNIST + "t10k-labels-idx1-ubyte.gz",
            "f7ae60f92e00ec6debd23a6088c31dbd2371eca3ffa0defaefb259924204aec6"),
    },
    "fashion_mnist": {
        "train-images-idx3-ubyte.gz": Remote(
            _FASHION + "train-images-idx3-ubyte.gz",
            "3aede38d61863908ad78613f6a32ed271626dd12800ba2636569512369268a84"),
        "train-labels-idx1-ubyte.gz": Remote(
            _FASHION + "train-labels-idx1-ubyte.gz",
            "a04f17134ac03560a47e3764e11b92fc97de4d1bfaf8ba1a3aa29af54cc90845"),
        "t10k-images-idx3-ubyte.gz": Remote(
            _FASHION + "t10k-images-idx3-ubyte.gz",
            "346e55b948d973a97e58d2351dde16a484bd415d4595297633bb08f03db6a073"),
        "t10k-labels-idx1-ubyte.gz": Remote(
            _FASHION + "t10k-labels-idx1-ubyte.gz",
            "67da17c76eaffca5446c3361aaab5c3cd6d1c2608764d35dfb1850b086bf8dd5"),
    },
    "cifar10": {
        "cifar-10-binary.tar.gz": Remote(
            _CIFAR + "cifar-10-binary.tar.gz",
            "c4a38c50a1bc5f3a1c5537f2155ab9d68f9f25eb1ed8d9ddda3db29a59bca1dd"),
    },
    "cifar100": {
        "cifar-100-binary.tar.gz": Remote(
            _CIFAR + "cifar-100-binary.tar.gz",
            "58a81ae192c23a4be8b1804d68e518ed807d710a4eb253b1f2a199162a40d8ec"),
    },
}

_NOT_DOWNLOADABLE = {
    "digits": "install it with: sudo apt-get install opencv-doc",
    "image_folder": "it is your own data: pass load('image_folder', root=...)",
}
_CHUNK = 1 << 20
_TIMEOUT_S = 60


def download(name: str, dest: str | os.PathLike | None = None, *,
             urls: dict[str, tuple[str, str]] | None = None) -> Path:
    """Fetch and verify the files of dataset `name` into `dest`; return `dest`.

    `dest` defaults to `$JAXNAT_DATA_DIR/<name>`, else `~/.cache/jaxnat/data/<name>`, both places
    `load` searches; a non-default `dest` can be passed to `load(name, root=dest)`. Files already
    present with the right hash are not fetched again. `urls` replaces the official sources with
    `{file name: (url, sha256)}` (a mirror, or a local server in tests).
    """
    if name not in REMOTES and name not in _NOT_DOWNLOADABLE:
        raise ValueError(f"unknown dataset {name!r}; downloadable: {', '.join(REMOTES)}")
    if urls is not None:
        remotes = {file: Remote(url, sha256.lower()) for file, (url, sha256) in urls.items()}
    elif name in REMOTES:
        remotes = REMOTES[name]
    else:
        raise ValueError(f"dataset {name!r} cannot be downloaded: {_NOT_DOWNLOADABLE[name]}")
    dest = Path(dest).expanduser() if dest is not None else default_download_dir(name)
    dest.mkdir(parents=True, exist_ok=True)
    for file, remote in remotes.items():
        if PurePosixPath(file).name != file or file in ("", ".", ".."):
            raise ValueError(f"download file name {file!r} must be a plain file name")
        target = dest / file
        fetched = not (target.is_file() and _sha256(target) == remote.sha256)
        if fetched:
            # A file there with the wrong hash is damaged: it goes first, so a failed fetch
            # leaves the target absent rather than corrupt.
            target.unlink(missing_ok=True)
            _fetch(remote, target)
        if file.endswith((".tar.gz", ".tgz")):
            _extract(target, dest, always=fetched)
    return dest


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(_CHUNK):
            digest.update(chunk)
    return digest.hexdigest()


def _fetch(remote: Remote, target: Path) -> None:
    """Stream `remote` to `target`.part, verify it, rename it to `target`."""
    part = target.with_name(target.name + ".part")
    try:
        _stream(remote.url, part)
        actual = _sha256(part)
        if actual != remote.sha256:
            raise DownloadError(f"{remote.url}: sha256 mismatch, expected {remote.sha256}, got "
                                f"{actual}; the file was damaged in transit or the source changed")
        os.replace(part, target)
    except Exception:
        # Ctrl-C (KeyboardInterrupt, not an Exception) keeps the .part for a later resume; after
        # a real error it may hold bad bytes, so it goes.
        part.unlink(missing_ok=True)
        raise


def _stream(url: str, part: Path) -> None:
    """Write the body at `url` to `part`, appending if `part` exists and the server resumes."""
    offset = part.stat().st_size if part.is_file() else 0
    headers = {"User-Agent": "jaxnat"}
    if offset:
        headers["Range"] = f"bytes={offset}-"
    try:
        with urllib.request.urlopen(urllib.request.Request(url, headers=headers),
                                    timeout=_TIMEOUT_S) as response:
            # A server that ignores Range answers 200 with the whole file: start over.
            resumed = offset > 0 and response.status == 206 and _range_start(response) == offset
            expected = response.headers.get("Content-Length")
            received = 0
            with open(part, "ab" if resumed else "wb") as f:
                while chunk := response.read(_CHUNK):
                    f.write(chunk)
                    received += len(chunk)
    except (OSError, http.client.HTTPException) as e:  # URLError and HTTPError are OSErrors
        raise DownloadError(f"downloading {url} failed: {e!r}; check the network, or fetch the "
                            f"file by hand into {part.parent}") from e
    if expected is not None and received != int(expected):
        raise DownloadError(f"downloading {url} failed: the connection closed after {received} "
                            f"of {expected} bytes; try again")


def _range_start(response: http.client.HTTPResponse) -> int | None:
    match = re.match(r"bytes (\d+)-", response.headers.get("Content-Range", ""))
    return int(match.group(1)) if match else None


def _extract(tarball: Path, dest: Path, *, always: bool) -> None:
    """Unpack `tarball` into `dest` unless (`always` is false and) its top folders all exist."""
    try:
        with tarfile.open(tarball, "r:*") as tar:
            members = tar.getmembers()
            for member in members:
                path = PurePosixPath(member.name)
                if path.is_absolute() or ".." in path.parts \
                        or not (member.isfile() or member.isdir()):
                    raise DatasetFormatError(
                        f"{tarball}: refusing to extract member {member.name!r}: only plain files "
                        "and folders with relative paths inside the archive are allowed")
            tops = {PurePosixPath(m.name).parts[0] for m in members if PurePosixPath(m.name).parts}
            if not always and all((dest / top).exists() for top in tops):
                return
            staging = Path(tempfile.mkdtemp(dir=dest, prefix=f".{tarball.name}."))
            try:
                # filter="data" (Python >= 3.11.4) re-checks paths and strips unsafe modes; the
                # member check above already makes extraction safe where it is missing.
                safe = {"filter": "data"} if hasattr(tarfile, "data_filter") else {}
                tar.extractall(staging, members=members, **safe)
                for top in tops:
                    final = dest / top
                    if final.is_dir() and not final.is_symlink():
                        shutil.rmtree(final)
                    elif final.exists() or final.is_symlink():
                        final.unlink()
                    os.replace(staging / top, final)
            finally:
                shutil.rmtree(staging, ignore_errors=True)
    except (tarfile.TarError, EOFError) as e:
        raise DatasetFormatError(f"{tarball}: cannot unpack ({e}); delete it and download "
                                 "again") from e
