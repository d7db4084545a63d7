"""Render a material exported with ``neuenh export --format mitsuba`` in Mitsuba 3, to EXR and PNG.

    .venv/bin/python examples/mitsuba_render.py out/chm_orange.xml [--spp 256] [--size 512] [-o render.png]

Registers the ``neuenh`` BSDF plugin (``neuenh.export.mitsuba``) in the ``llvm_ad_rgb`` variant,
loads the scene file the exporter wrote (the ball under the studio environment map) and writes the
linear render beside the PNG (``.exr``) and the PNG tone-mapped as ``neuenh render`` does.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from neuenh.export import mitsuba as nm  # noqa: E402
from neuenh.render.output import write_exr, write_png  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scene", type=Path)
    parser.add_argument("--spp", type=int, default=256)
    parser.add_argument("--size", type=int, default=512)
    parser.add_argument("-o", "--output", type=Path, default=Path("render.png"))
    args = parser.parse_args()
    mi = nm.set_variant("llvm_ad_rgb")
    nm.register()
    scene = mi.load_file(str(args.scene), spp=args.spp, size=args.size)
    start = time.perf_counter()
    image = mi.render(scene)
    import numpy as np

    image = np.array(image)
    print(f"rendered {args.scene} at {args.size}² and {args.spp} spp in {time.perf_counter() - start:.1f} s")
    write_exr(args.output.with_suffix(".exr"), image)
    write_png(args.output, image)
    print(f"wrote {args.output} and {args.output.with_suffix('.exr')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
