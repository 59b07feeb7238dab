"""Child process of :func:`pointcvx.io.cad.tessellate_cad`: ``python -m pointcvx.io._cad_child
PATH FMT MESH_SIZE OUT.npz`` meshes one CAD file in a fresh process (see :func:`child_main`)."""

import sys

from pointcvx.io.cad import child_main

if __name__ == "__main__":
    sys.exit(child_main(sys.argv[1:]))
