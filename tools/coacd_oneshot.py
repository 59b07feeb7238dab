"""What a CoACD user runs, for one-shot timings (docs/benchmarks.md): load a mesh, normalise it to
[-1, 1]^3, decompose at threshold 0.1, write the hulls as one OBJ.

    python tools/coacd_oneshot.py SHAPE.off OUT.obj      # prints the hull count
"""

import sys

import coacd
import numpy as np
import trimesh


def main(argv: list[str]) -> int:
    mesh = trimesh.load(argv[0], force="mesh")
    v = mesh.vertices - (mesh.bounds[0] + mesh.bounds[1]) / 2
    v = v / np.abs(v).max()
    coacd.set_log_level("error")
    parts = coacd.run_coacd(coacd.Mesh(v, mesh.faces), threshold=0.1)
    trimesh.util.concatenate([trimesh.Trimesh(p[0], p[1]) for p in parts]).export(argv[1])
    print(len(parts))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
