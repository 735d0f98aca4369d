"""One configuration front door: :class:`RunConfig`, the settings of a whole run in one file, with named presets.

A TOML (or JSON) file with up to three sections and an optional preset (``docs/configuration.md``)::

    preset = "cluttered"            # default | cluttered | seabed | depth-camera (PRESETS); the file overrides it

    [pipeline]                      # the scan pipeline: semslam.pipeline.PipelineConfig's fields
    reject_margin = 2.0
    [pipeline.segmentation]         # its nested tables: segmentation, pose, parts, attached
    max_planes = 2

    [slam.motion]                   # the filter: semslam.slam.SlamConfig's sections
    velocity_rw_mps_per_sqrt_s = [0.02, 0.01, 0.01]
    [slam.initialisation]           # (gating, initialisation, map, output likewise)
    initial_position_sigma_m = 0.5

    [run]                           # how the run goes: modes, backend, seed, keep_unreliable, up_from_attitude
    modes = ["pose", "pose+heading"]

The model is pydantic (v2): unknown keys are errors, types are strict (``"false"`` is not a bool, ``true`` is not a
number), numbers finite. The ``pipeline`` and ``slam`` sections are generated from the dataclasses the recogniser
and the filter use (:class:`~semslam.pipeline.PipelineConfig`, :class:`~semslam.slam.SlamConfig`), so their fields
and defaults have one source; the dataclasses' own checks (ranges, choices, ``semslam.limits``) run when a file is
loaded. Every error is one :class:`~semslam.errors.ConfigError` line naming the file, the key (dotted path) and the
problem.

Older files load unchanged: a ``[slam]`` and/or ``[pipeline]`` table, the bare fields of either at the top (a
``semslam slam`` run's ``config.json``), ``semslam detect``'s ``OUT.config.json`` and ``semslam demo``'s
``config.json``.
"""

from __future__ import annotations

import dataclasses
import os
import re
import types
import typing
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (AllowInfNan, BaseModel, ConfigDict, Field, Strict, StrictBool, StrictInt, StrictStr,
                      ValidationError, create_model, field_validator)

from ..errors import ConfigError, SemslamError
from ..pipeline.config import PipelineConfig
from ..slam.config import MODES, SlamConfig

from ..modes import BACKENDS

__all__ = ["BACKENDS", "CONFIG_FILE", "PRESETS", "RunConfig", "RunSection", "load_run_config",
           "write_resolved_config"]

#: the resolved configuration a run writes into its output directory
CONFIG_FILE = "config.toml"

FiniteFloat = Annotated[float, Strict(), AllowInfNan(False)]

# --- the pipeline and slam sections, generated from the dataclasses ------------------------------------------------

_SCALARS: dict[Any, Any] = {float: FiniteFloat, int: StrictInt, bool: StrictBool, str: StrictStr,
                            type(None): type(None)}
#: generated model class -> the dataclass it validates for
_DATACLASS_OF: dict[type, type] = {}


def _tuple_type(default: Any) -> Any:
    """A bare ``tuple`` annotation: a tuple of the default's element type (floats when the default is None)."""
    if isinstance(default, tuple) and default and all(isinstance(v, str) for v in default):
        return tuple[StrictStr, ...]
    return tuple[FiniteFloat, ...]


def _field_type(tp: Any, default: Any) -> Any:
    """The pydantic type of a dataclass field's annotation (strict scalars, tuples from lists, nested models)."""
    args = typing.get_args(tp) if isinstance(tp, types.UnionType) or typing.get_origin(tp) is typing.Union else ()
    if args:
        out = [_field_type(a, default) for a in args]
        return typing.Union[tuple(out)]  # noqa: UP007 (built from a list)
    if tp in _SCALARS:
        return _SCALARS[tp]
    if tp is tuple:
        return _tuple_type(default)
    if dataclasses.is_dataclass(tp):
        return _section_model(tp)
    raise TypeError(f"semslam.run.config: no pydantic type for the annotation {tp!r}")  # a new field type: extend


_MODELS: dict[type, type] = {}


def _section_model(cls: type) -> type[BaseModel]:
    """A frozen, extra-forbidding pydantic model with the dataclass ``cls``'s fields, types and defaults."""
    if cls in _MODELS:
        return _MODELS[cls]
    hints = typing.get_type_hints(cls)
    fields_: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        ftype = _field_type(hints[f.name], f.default)
        if f.default is not dataclasses.MISSING:
            fields_[f.name] = (ftype, f.default)
        elif f.default_factory is not dataclasses.MISSING:  # a nested section: its model's defaults
            sub = _field_type(hints[f.name], None)
            fields_[f.name] = (ftype, Field(default_factory=sub))
        else:
            fields_[f.name] = (ftype, ...)
    model = create_model(f"{cls.__name__}Section", __config__=ConfigDict(extra="forbid", frozen=True),
                         __doc__=f"The fields of :class:`{cls.__module__}.{cls.__name__}`.", **fields_)
    _MODELS[cls] = model
    _DATACLASS_OF[model] = cls
    return model


PipelineSection = _section_model(PipelineConfig)
SlamSection = _section_model(SlamConfig)


class RunSection(BaseModel):
    """How a run goes (the options every command shares; a command-line option given explicitly wins)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    #: SLAM modes run in one pass (``semslam run``/``batch``: all four by default; ``semslam slam``: ``pose``)
    modes: tuple[Literal[MODES], ...] = MODES  # type: ignore[valid-type]
    #: SLAM estimator: the EKF, or a GTSAM factor graph (isam2 online, batch)
    backend: Literal[BACKENDS] = "ekf"  # type: ignore[valid-type]
    #: seed of recognition (and of the simulated truth-based detections of ``semslam slam``)
    seed: Annotated[int, Strict(), Field(ge=0)] = 0
    #: ``semslam detect``: also keep the detections whose pose is unreliable
    keep_unreliable: StrictBool = False
    #: pose every scan's objects upright about the up direction of the vehicle's attitude at that scan
    up_from_attitude: StrictBool = False

    @field_validator("modes")
    @classmethod
    def _modes_unique(cls, v: tuple) -> tuple:
        if not v or len(set(v)) != len(v):
            raise ValueError(f"must name one or more distinct modes of {list(MODES)}")
        return v


# --- presets --------------------------------------------------------------------------------------------------------

#: Named partial configurations (docs/configuration.md says what each is for and what it was measured to do).
PRESETS: dict[str, dict] = {
    # today's defaults: PipelineConfig() and SlamConfig()
    "default": {},
    # cluttered scenes (rocks, debris, many classes): benchmarks/catalogue.py's CONFIGS["catalogue_border_floor_gaps"],
    # its best-measured setting (benchmarks/RESULTS.md): hypothesis verification, border-cut clusters flagged and
    # verified against the scene, sizes along principal axes, part-based unions, no posed object more than 10 mm
    # inside the floor it lies on (a rock posed as a fitting: clutter accepted 2.2-8.5 % -> 0-0.5 %), parts unioned
    # across the gaps the class's own views show (a wet-mate receptacle's cap and flange 8 cm apart), up to four
    # clusters per union (a gate valve in four pieces), recognised clusters among them (a gate valve's body alone
    # verifies as a blind flange)
    "cluttered": {"pipeline": {"verify_min_fitness": 0.95, "verify_max_visibility": 0.15, "border": "flag",
                               "size_reference": "principal",
                               "parts": {"view_gaps": True, "max_parts": 4, "detected_parts": True},
                               "verify_visibility_image": "border",
                               "verify_max_plane_penetration_m": 0.01}},
    # objects resting on the seabed (their most probable resting pose, gravity from the AHRS), beside structure and
    # cut by the swath's border, among clutter: "cluttered" plus a second plane removed (a wall, a slope: an object
    # beside it is otherwise one cluster with it) and the pose search kept upright (half-turn flips resolved); its
    # floor check (cluttered's) chosen here: on seed 0 every right pose within 5.1 mm of the removed plane, a plate
    # taken for a thicker flange 14.3-15.6 mm inside it.
    # A cluster whose nearest class fails verification (or is too small for it) is tried as the next one (a strip
    # of the 12 mm valve-panel base, nearer the flange's face than the plate's: the flange 15 mm in the floor, the
    # plate verifies); a
    # border-cut cluster's translation searched across the object (a strip of a flange's rim: its centroid ~10 cm
    # from the whole view's; a union of clusters is searched the same way, since 2026-12-06: benchmarks/history/
    # catalogue.md, session 24). The pose search counts the scan's other clusters about a cluster as seen surfaces (a
    # handwheel split at its spokes, half of it posed half-turned with a confident covariance). With a laser database
    # verification also allows for the scanner camera's shadows (a wheel valve on its rim, only its top seen). The
    # upright search scores 256 of its 1296 orientations per up fully (a gate valve's right orientation ranked past
    # 96 by the fit of 48 points).
    # A border-cut cluster rejected alone, or taken alone for another class, is tried as the object the scan before
    # or after saw there, ICP from the prediction (semslam.pipeline.tracking; 3 cm from it at most; sessions 30-31:
    # catalogue seed 0 recall 92.4 -> 98.3 %, real models seeds 0 and 3 95.1 -> 98.1 and 89.1 -> 95.3 %, precision
    # unchanged or better).
    # Chosen on benchmarks/real_models.py seed 0 (RESULTS.md "Real data"); use a laser database (db build --vehicle)
    "seabed": {"pipeline": {"verify_min_fitness": 0.95, "verify_max_visibility": 0.15, "border": "flag",
                            "size_reference": "principal",
                            "parts": {"view_gaps": True, "max_parts": 4, "detected_parts": True},
                            "verify_visibility_image": "border",
                            "verify_max_plane_penetration_m": 0.01, "verify_next_classes": 1,
                            "verify_camera_shadows": True, "pose_surroundings": True,
                            "pose": {"partial_start_step_m": 0.04, "n_candidates": 256},
                            "segmentation": {"max_planes": 2}, "track_border_cut_m": 0.03},
               "run": {"up_from_attitude": True}},
    # a RealSense/Kinect frame ~30 cm from the object (docs/depth-camera.md):
    # --max-range 0.5 --voxel auto --cluster-tolerance auto --max-planes 0 --up 0,-1,0 --reject-margin 1
    "depth-camera": {"pipeline": {"segmentation": {"drop_origin": True, "max_range_m": 0.5, "voxel_leaf_m": "auto",
                                                   "cluster_tolerance_m": "auto", "max_planes": 0},
                                  "up_scanner": [0.0, -1.0, 0.0], "reject_margin": 1.0}},
}


class RunConfig(BaseModel):
    """The settings of a run: ``pipeline`` (scan to detections), ``slam`` (the filter), ``run`` (modes, backend,
    seed, ...), and the ``preset`` they started from. Build with :func:`load_run_config`; hand the recogniser and
    the filter :meth:`pipeline_config` and :meth:`slam_config`."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    preset: Literal[tuple(PRESETS)] = "default"  # type: ignore[valid-type]
    pipeline: PipelineSection = Field(default_factory=PipelineSection)  # type: ignore[valid-type]
    slam: SlamSection = Field(default_factory=SlamSection)  # type: ignore[valid-type]
    run: RunSection = Field(default_factory=RunSection)

    def pipeline_config(self) -> PipelineConfig:
        """The :class:`~semslam.pipeline.PipelineConfig` of the ``pipeline`` section."""
        return _to_dataclass(self.pipeline, "pipeline")

    def slam_config(self) -> SlamConfig:
        """The :class:`~semslam.slam.SlamConfig` of the ``slam`` section."""
        return _to_dataclass(self.slam, "slam")

    def resolved_dict(self) -> dict:
        """Every value (None for an option that is off), the preset named: what a run writes into its output.
        :func:`load_run_config` of it gives this configuration back."""
        return self.model_dump(mode="json")

    def with_run(self, **options: Any) -> "RunConfig":
        """A copy with the named ``run`` options changed (validated; the command line's explicit options)."""
        try:
            run = RunSection.model_validate({**self.run.model_dump(exclude_unset=True), **options})
        except ValidationError as exc:
            raise ConfigError(_one_line(exc, "the command-line options", prefix=("run",))) from None
        return self.model_copy(update={"run": run})

    @classmethod
    def from_dict(cls, d: Any, *, source: str = "a RunConfig record", preset: str | None = None) -> "RunConfig":
        """From a table of the file format (:meth:`resolved_dict`'s form, or any part of it, or an older
        ``[slam]``/``[pipeline]`` file's); ``preset`` as :func:`load_run_config`'s. Errors name ``source``."""
        return _from_table(d, source, preset)


# --- building, loading, writing ---------------------------------------------------------------------------------------

_FIELD_IN_MESSAGE = re.compile(r"The '(\w+)' (?:field|argument)")


def _to_dataclass(section: BaseModel, path: str):
    """The dataclass of a validated section (nested ones first); its own checks' errors become one ConfigError
    naming the key."""
    cls = _DATACLASS_OF[type(section)]
    kw = {}
    for name in type(section).model_fields:
        v = getattr(section, name)
        kw[name] = _to_dataclass(v, f"{path}.{name}") if isinstance(v, BaseModel) else v
    try:
        return cls(**kw)
    except SemslamError as exc:
        msg = " ".join(str(exc).split())
        m = _FIELD_IN_MESSAGE.search(msg)
        key = f"{path}.{m.group(1)}" if m and m.group(1) in kw else path
        raise _KeyError(key, msg) from None


class _KeyError(ConfigError):
    """A dataclass check's error with the key it concerns (re-raised by the loader with the file named)."""

    def __init__(self, key: str, problem: str) -> None:
        super().__init__(f"key {key!r}: {problem}")
        self.key, self.problem = key, problem


def _model_at(loc: tuple) -> list[str]:
    """The dotted key of a pydantic error location: the model fields along it, tuple indices as [i], union branch
    tags left out."""
    model: Any = RunConfig
    out: list[str] = []
    for item in loc:
        if isinstance(item, int):
            if out:
                out[-1] += f"[{item}]"
            continue
        if model is not None and item in model.model_fields:
            out.append(item)
            ann = model.model_fields[item].annotation
            cands = typing.get_args(ann) or (ann,)
            model = next((c for c in cands if isinstance(c, type) and issubclass(c, BaseModel)), None)
        elif model is not None:  # an unknown key (extra_forbidden) of this model
            out.append(item)
            model = None
    return out


def _expected_keys(loc: tuple) -> list[str]:
    model: Any = RunConfig
    for item in loc[:-1]:
        if model is None or item not in model.model_fields:
            return []
        ann = model.model_fields[item].annotation
        cands = typing.get_args(ann) or (ann,)
        model = next((c for c in cands if isinstance(c, type) and issubclass(c, BaseModel)), None)
    return sorted(model.model_fields) if model is not None else []


def _one_line(exc: ValidationError, source: str, prefix: tuple = ()) -> str:
    """pydantic's errors as one line: the source, each key (dotted) and its problem."""
    problems: dict[str, list[str]] = {}
    for err in exc.errors(include_url=False):
        loc = prefix + tuple(err["loc"])
        key = ".".join(_model_at(loc)) or "(top level)"
        if err["type"] == "extra_forbidden":
            expected = _expected_keys(loc)
            text = "unknown key" + (f" (expected one of {expected})" if expected else "")
        else:
            text = err["msg"][0].lower() + err["msg"][1:]
            if err["type"] not in ("missing",):
                text += f", got {err['input']!r}"
        if text not in problems.setdefault(key, []):
            problems[key].append(text)
    parts = [f"key {k!r}: {' or '.join(v)}" for k, v in problems.items()]
    shown = "; ".join(parts[:3]) + (f"; and {len(parts) - 3} more" if len(parts) > 3 else "")
    return " ".join(f"{source}: {shown}.".split())


_PIPELINE_KEYS = frozenset(f.name for f in dataclasses.fields(PipelineConfig))
_SLAM_KEYS = frozenset(f.name for f in dataclasses.fields(SlamConfig))
#: keys of ``semslam detect``'s OUT.config.json that record the run's inputs, not settings
_DETECT_RECORD_KEYS = frozenset({"db", "mission"})


def _normalise_legacy(raw: dict) -> dict:
    """Older layouts as the sectioned one: bare SlamConfig sections or PipelineConfig fields at the top, and
    ``semslam detect``'s OUT.config.json (its inputs dropped, its options moved to ``run``)."""
    keys = set(raw)
    if keys and keys <= _SLAM_KEYS:
        return {"slam": raw}
    if keys and keys <= _PIPELINE_KEYS:
        return {"pipeline": raw}
    if "demo" in keys and keys <= {"demo", "simulator", "pipeline", "slam", "database"}:
        # `semslam demo`'s config.json: the pipeline, and the filter when every mode ran with the same settings
        out = {"pipeline": raw["pipeline"]} if "pipeline" in raw else {}
        per_mode = raw.get("slam")
        if isinstance(per_mode, dict) and per_mode:
            first = next(iter(per_mode.values()))
            if all(v == first for v in per_mode.values()):  # else no one filter setting to repeat: left out
                out["slam"] = first
        return out
    run_opts = {"seed", "keep_unreliable", "up_from_attitude"}
    if "pipeline" in keys and "run" not in keys and keys & _DETECT_RECORD_KEYS and keys <= (
            {"pipeline", "slam", "preset"} | run_opts | _DETECT_RECORD_KEYS):
        out = {k: raw[k] for k in keys & {"pipeline", "slam", "preset"}}
        run = {k: raw[k] for k in keys & run_opts}
        return {**out, "run": run} if run else out
    return raw


def _merge(base: dict, over: dict) -> dict:
    out = dict(base)
    for k, v in over.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def _from_table(raw: Any, source: str, preset: str | None) -> RunConfig:
    if not isinstance(raw, dict):
        raise ConfigError(f"{source} must be a table of settings. Got {type(raw).__name__} instead.")
    raw = _normalise_legacy(raw)
    if preset is not None and preset not in PRESETS:
        raise ConfigError(f"Unknown preset {preset!r}: expected one of {sorted(PRESETS)}.")
    named = raw.get("preset")
    if isinstance(named, str) and named in PRESETS and preset is not None and named != preset:
        raise ConfigError(f"{source}: key 'preset': the file names the preset {named!r}, the command line "
                          f"{preset!r}; give one.")
    name = preset if preset is not None else named if isinstance(named, str) and named in PRESETS else None
    merged = _merge(PRESETS[name] if name else {}, raw)
    if name:
        merged["preset"] = name
    try:
        cfg = RunConfig.model_validate(merged)
        cfg.pipeline_config(), cfg.slam_config()  # the dataclasses' own checks (ranges, choices, limits)
    except ValidationError as exc:
        raise ConfigError(_one_line(exc, source)) from None
    except _KeyError as exc:
        raise ConfigError(f"{source}: key {exc.key!r}: {exc.problem}") from None
    return cfg


def load_run_config(path: str | os.PathLike | None = None, preset: str | None = None) -> RunConfig:
    """The run configuration of a TOML (or ``.json``) file, on top of a named preset (``preset``, or the file's
    ``preset = "..."``; both: they must agree), or the preset alone, or the defaults.

    Raises :class:`~semslam.errors.ConfigError` (one line naming the file, the key and the problem) for an unknown
    key or preset, a wrong type, a value out of range.
    """
    if path is None:
        return _from_table({}, f"The preset {preset!r}", preset)
    from .._tables import read_table

    raw = read_table(path, "configuration file", ConfigError)
    return _from_table(raw, f"The configuration file {str(path)!r}", preset)


def _drop_none(d: Any) -> Any:
    if isinstance(d, dict):
        return {k: _drop_none(v) for k, v in d.items() if v is not None}
    return d


def write_resolved_config(config: RunConfig, out_dir: str | os.PathLike) -> Path:
    """Write ``config.toml`` (atomically) into ``out_dir``: every setting of the run (an option that is off, None,
    is left out: TOML has no null), the preset named. ``--config`` of it repeats the run's settings."""
    import tomli_w

    from .._atomic import atomic_write_text

    d = _drop_none(config.resolved_dict())
    head = (f"# semslam: the resolved configuration of this run (preset {config.preset!r}, every value).\n"
            "# `--config` of this file repeats these settings; an absent key is an option that is off.\n")
    path = Path(out_dir) / CONFIG_FILE
    atomic_write_text(path, head + tomli_w.dumps(d))
    return path
