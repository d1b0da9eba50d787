"""Compare localizer configurations on the same simulated queries, paired: what a change gains and loses.

How the localizer's knobs were chosen (``docs/localization.md``, "Measured alternatives"): every variant
localizes the SAME queries of the realistic scenario, so a difference of a few queries is the change's,
not the draw's. Each query is simulated once and cached (``--cache DIR``), so trying another variant
costs only its localizations. The cache is keyed by the city's content (``citymodel.tiles.city_sha256`` of
the city file or store and of the reality model the queries are drawn from, so two cities whose files share
a name, or a city file edited in place, are told apart), seed and ``--set``, and stamped with the code that
simulated it (``code_fingerprint`` of everything but ``localization/``): after any change outside the
localizer, the queries are simulated again. A malformed argument (a seed list, ``--workers``, a ``--cache``
that is a file, an unknown preset, a city that is not there, a variant value of the wrong type for its
field) is refused in one line before anything is simulated.

Usage::

    python benchmarks/compare_configs.py --variant base \\
        --variant top1:refine.polish_estimate_top=1 --variant nodepth:no_depth=true \\
        [--city generated --city FUERTH] [--seeds 0,1] [--queries 100] [--preset default]
        [--set seg_quality=medium] [--condition realistic --condition map_faults] [--workers 2] [--cache DIR]

A variant is ``NAME`` (the preset unchanged) or ``NAME:key=value,key=value`` with keys the preset's
``LocalizerConfig`` fields, dotted into its nested configs (``refine.polish_estimate_top=1``,
``cascade.local.keep=4``); values are parsed like ``semcityloc benchmark --set`` (JSON where they can be,
so ``refine.polish_sigma=[0.5,0.5,0.3,0.15]``). ``--set`` changes the simulated queries (scenario knobs).
``mean_s`` is measured with ``--workers`` processes sharing the cores: compare speed with
``bench_localize.py``, not here.

Tuning discipline: choose on the calibration cities only (the generated city and Fürth, the defaults); another
city (Berlin, Den Haag) is refused unless ``--check-only`` says the run is a check of a choice already made,
never a way to make one. Their realistic draws are easier than the reporting cities' (stop 53), so choose
under the map's faults too: ``--condition NAME`` (repeatable; ``realistic`` by default) runs every city and
seed under a named tuning condition (``benchmark.calibration.TUNING_CONDITIONS``: ``hilly``, ``flat_eaves``,
``outdated``, ``map_err2x``, ``map_faults`` (hilly, outdated and map_err2x at once), ``imu2x``, ``imu4x``),
each with ``--set`` on top, and summarises each condition apart.

Prints one JSON line per condition and variant (``condition`` names it): found-pose recall (accepted or not)
and accepted recall at 2 m / 2 deg, 3 m / 3 deg, 5 m / 5 deg, localized count, mean seconds per query, and,
for every variant after the first, how many queries it gains and loses against the first at 2 m / 2 deg, 3 m /
3 deg and 5 m / 5 deg (found poses: ``gained_2m``, ``lost_2m``, ...) and ``moves``: how many queries went from
one error band to another (bands ``2m``, ``3m``, ``5m``, ``off``: within 2 m / 2 deg, 3 m / 3 deg, 5 m / 5
deg, or beyond), e.g. ``{"2m->3m": 5, "off->2m": 1}``: whether a change trades fine poses for far misses shows
there at a glance (``--rows`` keeps every query's errors, to name them).
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import math
import pickle
import re
import sys
import time
import types
import typing
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from semcityloc.benchmark.calibration import (
    TUNING_CONDITIONS,
    calibration_cities,
    require_calibration_cities,
    tuning_condition,
)
from semcityloc.benchmark.code_version import code_fingerprint
from semcityloc.benchmark.scenario import parse_value, query_config
from semcityloc.benchmark.spec import BenchmarkSpec, load_map
from semcityloc.citymodel.tiles import city_sha256
from semcityloc.cli.benchmark import parse_settings  # the command line's --set knob=value
from semcityloc.errors import BenchmarkConfigError, ParameterError, SemCityLocError
from semcityloc.evaluation.metrics import THRESHOLDS, pose_errors, recall
from semcityloc.geometry.pose import Pose
from semcityloc.localization.config import LocalizerConfig
from semcityloc.localization.localize import Localizer
from semcityloc.localization.map_scenes import localizer_scene, scene_key
from semcityloc.localization.result import LOCALIZED
from semcityloc.render.scene import RenderScene

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"

_WORKER: dict[str, Any] = {}


def _fits(value: Any, hint: Any) -> bool:
    """Does ``value`` (parsed like ``--set``'s) fit a config field annotated ``hint``? A JSON list fits a
    tuple field; an int fits a float field, a bool no number field; an annotation not known here: any."""
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        return any(_fits(value, arg) for arg in typing.get_args(hint))
    if hint is type(None):
        return value is None
    if hint is bool:
        return isinstance(value, bool)
    if hint is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if hint is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if hint is str:
        return isinstance(value, str)
    if origin in (tuple, list) or hint in (tuple, list):
        return isinstance(value, (list, tuple))
    if origin is dict or hint is dict:
        return isinstance(value, dict)
    if dataclasses.is_dataclass(hint):
        return dataclasses.is_dataclass(value)
    return True


def with_overrides(config: Any, items: dict[str, Any]) -> Any:
    """``config`` (a frozen dataclass) with dotted ``items`` replaced in it or its nested dataclasses; a
    field it lacks or a value of another type than the field's is refused in one line (``SystemExit``)."""
    direct: dict[str, Any] = {}
    nested: dict[str, dict[str, Any]] = {}
    fields = {f.name for f in dataclasses.fields(config)}
    hints = typing.get_type_hints(type(config))
    for key, value in items.items():
        head, _, rest = key.partition(".")
        if head not in fields:
            raise SystemExit(
                f"{type(config).__name__} has no field {head!r} (fields: {', '.join(sorted(fields))})"
            )
        if rest:
            nested.setdefault(head, {})[rest] = value
        elif not _fits(value, hints.get(head, Any)):
            shown = getattr(hints.get(head), "__name__", None) or str(hints.get(head))
            raise SystemExit(f"{type(config).__name__}.{head} takes {shown}, got {value!r}")
        else:
            direct[head] = value
    for head, sub in nested.items():
        direct[head] = with_overrides(getattr(config, head), sub)
    return dataclasses.replace(config, **direct)


def parse_variant(text: str, preset: str) -> tuple[str, LocalizerConfig]:
    name, _, rest = text.partition(":")
    items = {}
    for part in filter(None, re.split(r",(?=[\w.]+=)", rest)):  # a comma starts a pair only before key=
        key, eq, value = part.partition("=")
        if not eq:
            raise SystemExit(f"variant {name!r}: expected key=value, got {part!r}")
        items[key.strip()] = parse_value(value.strip())
    try:
        base = LocalizerConfig.preset(preset)
        return name, with_overrides(base, items)
    except (ParameterError, ValueError, TypeError) as exc:  # an unknown preset, a config's own check
        raise SystemExit(f"variant {name!r}: {exc}") from None


def _spec(city: str, seed: int, queries: int, settings: dict[str, Any]) -> BenchmarkSpec:
    return BenchmarkSpec(city=city, query=query_config("realistic", settings, queries=queries, seed=seed))


def city_key(city: str) -> str:
    """The cache's name of ``city``: its file's stem and a digest of what its queries are simulated from,
    the city file or store (``city_sha256``) and the reality model (``generated_lod3.gml`` beside a
    generated city, else the city itself). ``InputFileError`` when ``city`` is not there."""
    config = _spec(city, 0, 1, {}).run_config()
    sources = [city_sha256(config["city_path"]), city_sha256(config["reality_source"])]
    return f"{Path(city).stem}-{hashlib.sha256(' '.join(sources).encode()).hexdigest()[:12]}"


def _cache_dir(root: Path, city_name: str, seed: int, settings: dict[str, Any]) -> Path:
    """The cache folder of ``city_name`` (``city_key``), ``seed`` and the ``--set`` ``settings``."""
    tag = "_".join(f"{k}={v}" for k, v in sorted(settings.items())).replace("/", "-") or "realistic"
    if len(tag) > 80:  # many knobs: a file name has at most 255 bytes
        tag = "set-" + hashlib.sha256(tag.encode()).hexdigest()[:16]
    return root / f"{city_name}_s{seed}_{tag}"


def parse_seeds(text: str) -> list[int]:
    """``--seeds`` (comma-separated integers >= 0), refused in one line when malformed."""
    try:
        seeds = [int(s) for s in text.split(",")]
    except ValueError:
        raise SystemExit(f"--seeds takes comma-separated integers, e.g. 0,1; got {text!r}") from None
    if any(s < 0 for s in seeds):
        raise SystemExit(f"--seeds must be >= 0, got {text!r}")
    return seeds


def reset_if_stale(folder: Path, fingerprint: str) -> None:
    """Drop the queries cached in ``folder`` unless its stamp names ``fingerprint`` (the simulation's code);
    a folder without a stamp is stale. Stamps the folder for what is simulated next."""
    stamp = folder / "simulation_code.txt"
    if stamp.is_file() and stamp.read_text(encoding="utf-8").strip() == fingerprint:
        return
    stale = sorted(folder.glob("q*.pkl"))
    if stale:
        print(
            f"{folder.name}: {len(stale)} cached queries come from other code; simulating them again",
            file=sys.stderr,
        )
        for path in stale:
            path.unlink()
    stamp.write_text(fingerprint + "\n", encoding="utf-8")


def _init_simulate(city: str, seed: int, queries: int, settings: dict[str, Any]) -> None:
    spec = _spec(city, seed, queries, settings)
    _WORKER["source"] = spec.open_source(spec.run_config())


def _simulate(args: tuple[int, Path]) -> None:
    index, path = args
    q = _WORKER["source"].query(index)
    tmp = path.with_suffix(".tmp")
    tmp.write_bytes(pickle.dumps(q))
    tmp.replace(path)


def _init_localize(city: str, seed: int, queries: int, settings: dict, variants: list) -> None:
    spec = _spec(city, seed, queries, settings)
    model = load_map(spec.run_config())
    scenes: dict[tuple, RenderScene] = {}  # one per map (eaves); each Localizer adapts its classes
    localizers = []
    for name, cfg in variants:
        key = scene_key(cfg)
        if key not in scenes:
            scenes[key] = localizer_scene(model, cfg)
        localizers.append((name, Localizer(model, cfg, scene=scenes[key])))
    _WORKER["localizers"] = localizers


def _localize(path: Path) -> list[dict] | None:
    q = pickle.loads(path.read_bytes())
    if not q.meta.get("accepted", True):
        return None
    rows = []
    for name, loc in _WORKER["localizers"]:
        t0 = time.perf_counter()
        r = loc.localize(q.camera, q.prior_pose_local, q.labels, q.depth)
        seconds = time.perf_counter() - t0
        err_m, err_deg, _ = pose_errors(r.found_pose_local, q.true_pose_local)
        query = f"{path.parent.name}/{q.query_id}"
        rows.append(
            {
                "variant": name,
                "query": query,
                "status": r.status,
                "s": seconds,
                "err_m": err_m,
                "err_deg": err_deg,
                "probability": r.confidence.get("probability"),
                "view_span_m": r.confidence.get("view_span_m"),
                "score": r.score,
                "semantic": r.semantic,
                "depth_cost": r.depth_cost,
                "building_iou": r.confidence.get("building_iou"),
                "flat_roof_eaves": r.search.get("flat_roof_eaves"),
                "roll_pitch_look": _look_errors(r.search.get("roll_pitch_conflict"), q.true_pose_local),
            }
        )
    return rows


def _look_errors(look: dict | None, true_pose_local: Pose) -> dict | None:
    """The roll/pitch second look's record with the errors (m, deg) of its first and second pose, so that
    a take rule can be judged on the same runs (``roll_pitch_takes.py``); None where it did not run."""
    if look is None:
        return None
    keep = ("departure_deg", "sigmas", "gain", "gain_needed", "moved_m", "moved_deg", "taken")
    out = {k: look[k] for k in keep}
    for which in ("first", "second"):
        pose = Pose.from_state(np.asarray(look[f"{which}_xyz_rpy_local"]))
        err_m, err_deg, _ = pose_errors(pose, true_pose_local)
        out[f"{which}_err"] = [float(err_m), float(err_deg)]
    return out


def _hits(rows: list[dict], m: float, deg: float) -> set[str]:
    return {r["query"] for r in rows if r["err_m"] <= m and r["err_deg"] <= deg}


def _band(row: dict) -> str:
    """The error band of a found pose: the first of THRESHOLDS it is within, else "off"."""
    for m, deg in THRESHOLDS:
        if row["err_m"] <= m and row["err_deg"] <= deg:
            return f"{m:g}m"
    return "off"


def _moves(rows: list[dict], reference: list[dict]) -> dict[str, int]:
    """Queries whose error band differs from the reference's, counted per "from->to", sorted."""
    before = {r["query"]: _band(r) for r in reference}
    pairs = ((before.get(r["query"]), _band(r)) for r in rows)
    return dict(sorted(Counter(f"{was}->{now}" for was, now in pairs if was not in (None, now)).items()))


def summarise(rows: list[dict], names: list[str]) -> list[dict]:
    """One summary per variant (module docstring), paired against the first. Errors are the found pose's
    (``inf`` when none); "accepted" counts a refused pose as a failure."""
    by = {n: [r for r in rows if r["variant"] == n] for n in names}
    out = []
    for name in names:
        rs = by[name]
        err_m = [r["err_m"] for r in rs]
        err_deg = [r["err_deg"] for r in rs]
        acc_m = [e if r["status"] == LOCALIZED else math.inf for e, r in zip(err_m, rs, strict=True)]
        s = {
            "variant": name,
            "queries": len(rs),
            "found_R@2/3/5": [round(recall(err_m, err_deg, m, d), 1) for m, d in THRESHOLDS],
            "accepted_R@2/3/5": [round(recall(acc_m, err_deg, m, d), 1) for m, d in THRESHOLDS],
            "localized": sum(r["status"] == LOCALIZED for r in rs),
            "mean_s": round(sum(r["s"] for r in rs) / max(len(rs), 1), 3),
        }
        if name != names[0]:
            for m, deg in THRESHOLDS:
                hit, hit0 = _hits(rs, m, deg), _hits(by[names[0]], m, deg)
                s[f"gained_{m:g}m"] = len(hit - hit0)
                s[f"lost_{m:g}m"] = len(hit0 - hit)
            s["moves"] = _moves(rs, by[names[0]])
        out.append(s)
    return out


def conditions_help() -> str:
    """``--condition``'s help: each name of ``TUNING_CONDITIONS`` with the knobs it sets, from the dict (a
    copied list would go stale when a condition is added or changed)."""
    said = [
        f"{name} ({', '.join(knobs) or 'the realistic scenario as it is'})"
        for name, knobs in TUNING_CONDITIONS.items()
    ]
    return (
        "a named tuning condition, its scenario knobs set as --set sets them, under --set's own (repeatable; "
        "default: realistic): " + "; ".join(said)
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--variant", action="append", required=True, help="NAME or NAME:key=value,...")
    ap.add_argument("--city", action="append", help="default: generated and Fürth")
    ap.add_argument("--seeds", default="0", help="comma-separated (default 0)")
    ap.add_argument("--queries", type=int, default=100)
    ap.add_argument("--preset", default="default")
    ap.add_argument("--set", action="append", default=[], help="scenario knob=value (benchmark --set)")
    ap.add_argument(
        "--condition",
        action="append",
        choices=list(TUNING_CONDITIONS),
        help=conditions_help(),
    )
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--cache", type=Path, default=Path(".compare_cache"))
    ap.add_argument("--rows", type=Path, help="write every (variant, query) row here as JSON lines")
    ap.add_argument("--check-only", action="store_true", help="allow a reporting city: a check, not a choice")
    args = ap.parse_args(argv)

    cities = args.city or calibration_cities(SHARED_DATA)
    seeds = parse_seeds(args.seeds)
    try:
        LocalizerConfig.preset(args.preset)
    except ParameterError as exc:
        raise SystemExit(f"--preset: {exc}") from None
    variants = [parse_variant(v, args.preset) for v in args.variant]
    names = [n for n, _ in variants]
    if len(set(names)) != len(names):
        raise SystemExit("variant names must differ")
    if args.workers < 1:
        raise SystemExit(f"--workers must be >= 1, got {args.workers}")
    if args.queries < 1:
        raise SystemExit(f"--queries must be >= 1, got {args.queries}")
    if args.cache.exists() and not args.cache.is_dir():
        raise SystemExit(f"--cache {args.cache}: is a file, not a folder")
    try:
        city_names = {city: city_key(city) for city in cities}  # a city that is not there: said here
    except SemCityLocError as exc:
        raise SystemExit(f"--city: {exc}") from None
    if not args.check_only:
        try:
            require_calibration_cities(cities, SHARED_DATA, "tune a knob")
        except ParameterError as exc:
            raise SystemExit(f"{exc} (--check-only to check a choice already made)") from None
    conditions = args.condition or ["realistic"]
    settings_of = {}
    for condition in conditions:
        try:
            settings_of[condition] = parse_settings([*tuning_condition(condition), *args.set])
            query_config("realistic", settings_of[condition])  # a bad knob fails here, not in a worker
        except BenchmarkConfigError as exc:
            raise SystemExit(f"--set: {exc}") from None
    rows: list[dict] = []
    fingerprint = code_fingerprint(exclude=("localization",))
    runs = [(c, city, s) for c in conditions for city in cities for s in seeds]
    for condition, city, seed in runs:
        settings = settings_of[condition]
        folder = _cache_dir(args.cache, city_names[city], seed, settings)
        folder.mkdir(parents=True, exist_ok=True)
        reset_if_stale(folder, fingerprint)
        paths = [folder / f"q{i:04d}.pkl" for i in range(args.queries)]
        missing = [(i, p) for i, p in enumerate(paths) if not p.is_file()]
        if missing:
            print(f"simulating {len(missing)} queries of {folder.name} ...", file=sys.stderr, flush=True)
            init = (city, seed, args.queries, settings)
            with ProcessPoolExecutor(args.workers, initializer=_init_simulate, initargs=init) as ex:
                list(ex.map(_simulate, missing))
        init = (city, seed, args.queries, settings, variants)
        with ProcessPoolExecutor(args.workers, initializer=_init_localize, initargs=init) as ex:
            for got in ex.map(_localize, paths):
                rows.extend({**r, "condition": condition} for r in got or [])
    if args.rows:
        args.rows.write_text("".join(json.dumps(r) + "\n" for r in rows))
    for condition in conditions:
        for s in summarise([r for r in rows if r["condition"] == condition], names):
            print(json.dumps({"condition": condition, **s}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
