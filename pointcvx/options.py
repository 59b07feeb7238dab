"""Every loading and decomposition option, declared once: name, type, default, range and help.

:class:`LoadOptions` and :class:`DecomposeOptions` are frozen dataclasses whose fields carry
their declaration (:func:`option`). From them come the checks of :func:`pointcvx.load` and
:func:`pointcvx.decompose` (made when an instance is built), the command-line flags of
``info``, ``decompose``, ``batch`` and ``bench`` (:mod:`pointcvx.flags`) and the settings of a
batch. Adding an option is one field here plus its use.
"""

from __future__ import annotations

import math
import numbers
import os
import re
from dataclasses import MISSING, Field, dataclass, field, fields
from typing import Any, ClassVar

from .errors import InputError

#: Where features come from (:func:`pointcvx.pipeline.resolve_features`).
FEATURE_METHODS = ("auto", "optimize", "model", "fast")
#: How a part is cut in two (:class:`pointcvx.decomposition.tree.Decomposer`).
SPLIT_METHODS = ("auto", "kmeans", "ward")
#: Physics engines whose per-hull caps :mod:`pointcvx.decomposition.limits` knows.
ENGINE_TARGETS = ("mujoco", "bullet", "physx", "physx-gpu", "newton", "unity")
#: How splats and scans are freed from their surroundings (:func:`pointcvx.scene.isolate`).
ISOLATE_MODES = ("auto", "all", "largest", "none")
#: How what stood on a removed support plane reaches down to it: its hulls
#: (pointcvx.decomposition.ground), its points (pointcvx.scene.base), or neither.
BASE_MODES = ("hulls", "on", "off")
#: Whether a capture is decomposed as a scene of objects (:mod:`pointcvx.scene.objects`).
SCENE_MODES = ("auto", "on", "off")
#: Where points are moved to the middle of their surface band first (pointcvx.scene.band).
BAND_MODES = ("auto", "on", "off")
#: Surface points :func:`pointcvx.decompose` works on when ``n_points`` is not given.
DECOMPOSE_POINTS = 20000


@dataclass(frozen=True)
class Spec:
    """How one option is checked and offered as a flag.

    Attributes
    ----------
    help : str
        One line for ``--help`` and the docs: what the option does and why one would change it.
    kind : type
        ``int``, ``float``, ``str``, ``bool``, ``os.PathLike`` (a path, kept as ``str``) or
        ``tuple`` (a box: six finite numbers, the min corner then the max corner).
    flag : str or None
        The long flag (``--threshold``); None: API only. Boolean options whose default is True
        are offered as ``--no-NAME`` flags.
    short : str, optional
    metavar : str, optional
    choices : tuple, optional
    low, high : float, optional
        Smallest and largest allowed values; ``low_open``/``high_open`` exclude them.
    optional : bool
        None is allowed (and means "off" or "automatic", as the help says).
    length : bool
        A number may also be given as a length with a unit (``"5mm"``, see :data:`LENGTH_UNITS`),
        kept as that text and converted where the input's scale is known.
    group : str
        Heading of the flag in ``--help``.
    """

    help: str
    kind: type
    flag: str | None
    short: str | None = None
    metavar: str | None = None
    choices: tuple | None = None
    low: float | None = None
    low_open: bool = False
    high: float | None = None
    high_open: bool = False
    optional: bool = False
    group: str = ""
    length: bool = False

    def describe_range(self) -> str:
        """The allowed values in words, for error messages."""
        if self.choices is not None:
            return "one of " + ", ".join(str(c) for c in self.choices)
        if self.low is not None and self.high is not None:
            left = "(" if self.low_open else "["
            right = ")" if self.high_open else "]"
            return f"in {left}{self.low:g}, {self.high:g}{right}"
        if self.low is not None:
            if self.low == 0 and self.low_open:
                return "positive"
            return f"{'more than' if self.low_open else 'at least'} {self.low:g}"
        if self.high is not None:
            return f"{'less than' if self.high_open else 'at most'} {self.high:g}"
        return "finite"


def option(default: Any, help: str, kind: type, flag: str | None, **spec: Any) -> Field:
    """A dataclass field declaring one option (see :class:`Spec` for ``spec``)."""
    return field(default=default, metadata={"spec": Spec(help=help, kind=kind, flag=flag, **spec)})


def spec_of(f: Field) -> Spec:
    return f.metadata["spec"]


def check_value(name: str, spec: Spec, value: Any) -> Any:
    """``value`` converted to the option's type; :class:`InputError` naming ``name`` when it is of
    the wrong type or outside the declared range."""
    import numpy as np  # here, not at the top: the command line's parsers need no numpy

    if value is None:
        if spec.optional:
            return None
        raise InputError(f"{name} must be set, got None")
    kind = spec.kind
    if spec.length and isinstance(value, str):
        metres = parse_length(value, name)
        if not metres > 0:
            raise InputError(f"{name} must be positive, got {value!r}")
        return value.strip().replace(" ", "")
    if kind is bool:
        if isinstance(value, (bool, np.bool_)):
            return bool(value)
        raise InputError(f"{name} must be True or False, got {value!r}")
    if kind is tuple:
        return _check_box(name, value)
    if kind is str:
        if not isinstance(value, str):
            raise InputError(f"{name} must be a string, got {type(value).__name__}")
    elif kind is os.PathLike:
        if not isinstance(value, (str, os.PathLike)):
            raise InputError(f"{name} must be a path, got {type(value).__name__}")
        return os.fspath(value)
    elif kind is int:
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
            raise InputError(f"{name} must be an integer, got {value!r}")
        value = int(value)
    elif kind is float:
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
            raise InputError(f"{name} must be a number, got {value!r}")
        value = float(value)
        if not math.isfinite(value):
            raise InputError(f"{name} must be finite, got {value}")
    if spec.choices is not None and value not in spec.choices:
        raise InputError(f"unknown {name} {value!r}; expected {spec.describe_range()}")
    if spec.low is not None and (value < spec.low or (spec.low_open and value == spec.low)):
        raise InputError(f"{name} must be {spec.describe_range()}, got {value}")
    if spec.high is not None and (value > spec.high or (spec.high_open and value == spec.high)):
        raise InputError(f"{name} must be {spec.describe_range()}, got {value}")
    return value


#: Units of lengths given as text (``--threshold 5mm``), in metres, and of ``units``.
LENGTH_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "um": 1e-6, "in": 0.0254, "ft": 0.3048}
_LENGTH = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([a-z]+)\s*$")


def parse_length(text: str, name: str = "length") -> float:
    """Metres of a length written with a unit (``"5mm"``, ``"0.5 cm"``, ``"2in"``)."""
    match = _LENGTH.match(text.lower())
    if match is None or match.group(2) not in LENGTH_UNITS:
        raise InputError(f"{name} must be a number or a length with a unit ({', '.join(LENGTH_UNITS)}), "
                         f"got {text!r}")
    value = float(match.group(1)) * LENGTH_UNITS[match.group(2)]
    if not math.isfinite(value):
        raise InputError(f"{name} must be finite, got {text!r}")
    return value


def _check_box(name: str, value: Any) -> tuple[float, ...]:
    """Six finite numbers (x0, y0, z0, x1, y1, z1) with x0 <= x1, y0 <= y1, z0 <= z1."""
    import numpy as np

    try:
        box = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be six numbers x0,y0,z0,x1,y1,z1, got {value!r}") from None
    if box.shape != (6,) or not np.isfinite(box).all():
        raise InputError(f"{name} must be six finite numbers x0,y0,z0,x1,y1,z1, got {value!r}")
    if (box[:3] > box[3:]).any():
        raise InputError(f"{name}: the first corner must not exceed the second, got {value!r}")
    return tuple(float(v) for v in box)


class Options:
    """Base of the option sets: every field is checked (and converted) when an instance is made."""

    KIND: ClassVar[str] = "option"

    def __post_init__(self) -> None:
        for f in fields(self):
            object.__setattr__(self, f.name, check_value(f.name, spec_of(f), getattr(self, f.name)))

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))

    @classmethod
    def defaults(cls) -> dict[str, Any]:
        return {f.name: f.default for f in fields(cls) if f.default is not MISSING}

    @classmethod
    def from_kwargs(cls, **kwargs: Any):
        """Build from keyword arguments; an unknown name is a :class:`TypeError` listing the known."""
        unknown = sorted(set(kwargs) - set(cls.names()))
        if unknown:
            raise TypeError(f"unknown {cls.KIND}(s): {', '.join(unknown)}; known: {', '.join(cls.names())}")
        return cls(**kwargs)

    def as_dict(self) -> dict[str, Any]:
        return {name: getattr(self, name) for name in self.names()}

    def changed(self) -> dict[str, Any]:
        """The options that differ from their defaults."""
        base = self.defaults()
        return {k: v for k, v in self.as_dict().items() if base.get(k, MISSING) != v}


_ALL = "loading (all inputs)"
_MESH = "meshes and CAD"
_SPLAT = "Gaussian splats"
_SCAN = "scans (point clouds without normals)"
_ISOLATE = "splats and scans: the object and its surroundings"


@dataclass(frozen=True)
class LoadOptions(Options):
    """Options of :func:`pointcvx.load`; :func:`pointcvx.decompose` takes them too."""

    KIND: ClassVar[str] = "load option"

    n_points: int | None = option(
        None, "cap the point count (meshes and CAD: how many surface samples to draw; default: "
        "mesh_points samples on meshes, every point of splats and scans)", int, "--points",
        short="-n", metavar="N", low=4, optional=True, group=_ALL)
    seed: int = option(0, "seed of every random choice: same seed, same result", int, "--seed",
                       low=0, high=2**32 - 1, group=_ALL)
    normalize: bool = option(True, "normalise to [-1, 1]^3 (the transform is kept on the cloud); "
                             "off keeps the input's units", bool, "--normalize", group=_ALL)
    mesh_points: int = option(20000, "surface samples drawn on a mesh when n_points is not given",
                              int, None, low=4)
    orient_rays: int = option(8, "rays per side in the outward test of mesh faces", int,
                              "--orient-rays", metavar="K", low=1, group=_MESH)
    cad_mesh_size: float = option(0.01, "CAD tessellation size as a fraction of the part's "
                                  "diagonal", float, "--cad-mesh-size", metavar="F", low=0,
                                  low_open=True, high=1, group=_MESH)
    min_opacity: float = option(0.1, "drop Gaussians whose opacity is below this", float,
                                "--min-opacity", metavar="A", low=0, high=1, high_open=True,
                                group=_SPLAT)
    floater_ratio: float = option(0.01, "drop clusters of Gaussians holding less than this share "
                                  "of all of them (0: keep every cluster)", float, "--floater-ratio",
                                  metavar="R", low=0, high=0.5, high_open=True, group=_SPLAT)
    samples_per_gaussian: int = option(1, "points drawn from each Gaussian's ellipsoid (1: its "
                                       "centre)", int, "--samples-per-gaussian", metavar="S", low=1,
                                       group=_SPLAT)
    outlier_neighbors: int = option(20, "neighbours of the statistical outlier removal of scans "
                                    "and splat centres (0: off)", int, "--outlier-neighbors",
                                    metavar="K", low=0, group=_SCAN)
    outlier_std: float = option(2.5, "a point is an outlier when its mean neighbour distance "
                                "exceeds the mean by this many standard deviations", float,
                                "--outlier-std", metavar="S", low=0, low_open=True, group=_SCAN)
    voxel_size: float | None = option(None, "voxel down-sampling size in input units (default: "
                                      "off)", float, "--voxel-size", metavar="V", low=0,
                                      low_open=True, optional=True, group=_SCAN)
    normal_neighbors: int = option(24, "neighbours used to estimate normals", int,
                                   "--normal-neighbors", metavar="K", low=3, group=_SCAN)
    isolate: str = option(
        "auto", "free the object from its surroundings: all removes the support plane (floor, "
        "table, ground disc) and small clutter pieces, largest keeps only the largest piece, none "
        "keeps everything; auto is all on splats and scans and none on meshes and CAD", str,
        "--isolate", choices=ISOLATE_MODES, group=_ISOLATE)
    crop: tuple | None = option(None, "keep only the points inside this box, in input units "
                                "(min corner, then max corner)", tuple, "--crop",
                                metavar="X0,Y0,Z0,X1,Y1,Z1", optional=True, group=_ISOLATE)
    close_bases: str = option(
        "hulls", "what stood on the removed support plane reaches down to it, instead of ending "
        "a band's height above it: hulls (default) extends the hulls that rest on it down to the "
        "plane (no hull added); on closes the points' bottom before the split (a cap on the "
        "plane and a skirt down to it: more hulls on some depth frames, see docs/captures.md); "
        "off leaves both open", str, "--close-bases", choices=BASE_MODES, group=_ISOLATE)


@dataclass(frozen=True)
class DecomposeOptions(Options):
    """Options of :func:`pointcvx.decompose` beyond loading (:class:`LoadOptions`)."""

    KIND: ClassVar[str] = "decomposition option"

    threshold: float | str = option(
        0.1, "concavity threshold: a part at most this concave is not split further; a number is "
        "in the normalised [-1, 1]^3 frame (relative to the shape's size), a length with a unit "
        "(5mm, 0.2in) is in the input's units (see units)", float, "--threshold", short="-t", low=0,
        low_open=True, length=True)
    max_hulls: int = option(64, "hull budget: never more hulls than this", int, "--max-hulls",
                            short="-k", low=1)
    features: str = option(
        "auto", "where the convex-aware features come from: optimised for the shape, the bundled "
        "feed-forward model, fast (the per-shape field fitted in a third of the steps, in numpy, "
        "without torch; opt-in), or auto (the model on splats, optimisation on other inputs)", str,
        "--features", choices=FEATURE_METHODS)
    model: str | None = option(None, "feed-forward model checkpoint (from `pointcvx train`) for "
                               "the model features; default: the bundled one", os.PathLike,
                               "--model", metavar="CKPT", optional=True)
    views: int = option(1, "with the model: encode the shape in this many orientations and use "
                        "the concatenated features (a test-time ensemble)", int, "--views",
                        metavar="V", low=1)
    merge: bool = option(True, "after splitting, join neighbouring parts whose joint hull stays "
                         "under the threshold", bool, "--merge")
    split: str = option("auto", "how a part is cut in two (auto: k-means on features and "
                        "position)", str, "--split", choices=SPLIT_METHODS)
    blend: float = option(1.0, "weight of position (scaled to the part's size) against features "
                          "when a part is cut", float, "--blend", low=0)
    subsurface: float | None = option(
        None, "leave points deeper than this inside the solid (normalised frame) out of the "
        "concavity measure, for splats whose Gaussians form a layer under the surface; off by "
        "default, since the walls of narrow folds read as deep too", float, "--subsurface",
        metavar="DEPTH", low=0, low_open=True, optional=True)
    band: str = option(
        "auto", "move each point along its normal to the middle of the surface band it scatters "
        "in (splat centres, sensor noise) before decomposing, so hulls sit on the surface, not "
        "on the band's outer edge: on, off, or auto (splats)", str, "--band", choices=BAND_MODES)
    target: str | None = option(
        None, "keep every hull within this engine's per-hull caps (reduced hulls still contain "
        "their part)", str, "--target", choices=ENGINE_TARGETS, optional=True)
    max_hull_vertices: int | None = option(None, "at most this many vertices per hull (with a "
                                           "target, the tighter cap wins)", int,
                                           "--max-hull-vertices", metavar="N", low=4, optional=True)
    units: str = option(
        "auto", "the length unit of the input's coordinates, for thresholds given as lengths: "
        "auto is mm for CAD parts (OpenCASCADE reads STEP in mm) and m for everything else",
        str, "--units", choices=("auto", *LENGTH_UNITS))
    scene: str = option(
        "auto", "decompose a scene capture object by object (one body per object in robot "
        "formats): on, off, or auto (depth frames, and captures whose isolation keeps several "
        "objects)", str, "--scene", choices=SCENE_MODES)
    timeout: float | None = option(
        None, "give up after this many seconds with an error and no output (loading included)",
        float, "--timeout", metavar="SECONDS", low=0, low_open=True, optional=True)


def split_kwargs(kwargs: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """Keyword arguments of :func:`pointcvx.decompose` split into (decomposition, loading) ones;
    a name of neither set is a :class:`TypeError`."""
    dec_names, load_names = set(DecomposeOptions.names()), set(LoadOptions.names())
    unknown = sorted(set(kwargs) - dec_names - load_names)
    if unknown:
        raise TypeError(f"unknown option(s): {', '.join(unknown)}; known: "
                        f"{', '.join(DecomposeOptions.names() + LoadOptions.names())}")
    return ({k: v for k, v in kwargs.items() if k in dec_names},
            {k: v for k, v in kwargs.items() if k in load_names})
