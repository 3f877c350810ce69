"""Copy the bundled demo photo from scikit-image's data folder (run once; needs scikit-image).

    python assets/photos/make_demo_photo.py

Writes ``assets/photos/astronaut.png`` (512×512 sRGB PNG, byte-identical to scikit-image's
``skimage/data/astronaut.png``) and prints its SHA-256.
"""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import skimage.data


def main() -> None:
    source = Path(skimage.data.__file__).parent / "astronaut.png"
    target = Path(__file__).with_name("astronaut.png")
    shutil.copyfile(source, target)
    print(target, hashlib.sha256(target.read_bytes()).hexdigest())


if __name__ == "__main__":
    main()
