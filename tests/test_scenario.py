"""Scenarios and knobs of the simulated benchmark: the realistic prior and depth, --set, sweep, report."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from semcityloc.benchmark.depth_sim import DepthParams, simulate_depth_realistic
from semcityloc.benchmark.perception_sim import simulate_depth
from semcityloc.benchmark.queries import (
    STREAM_PRIOR,
    STREAM_PRIOR_EXTRA,
    STREAM_PRIOR_REALISTIC,
    QueryConfig,
    sample_prior,
)
from semcityloc.benchmark.scenario import (
    SCENARIOS,
    knob_names,
    parse_value,
    query_config,
    set_knobs,
)
from semcityloc.cli.benchmark import parse_settings
from semcityloc.errors import BenchmarkConfigError, as_flags
from semcityloc.geometry.pose import Pose

TRUE = Pose.from_xyz_rpy([100.0, 200.0, 90.0], 1.0, 35.0, 40.0)


def prior_errors(cfg: QueryConfig, n: int = 600) -> np.ndarray:
    """(n, 5): dx, dy, dz, roll error, pitch error of the priors of n queries."""
    out = []
    for i in range(n):
        realistic = cfg.prior_height_m is not None or cfg.prior_roll_pitch_sigma_deg is not None
        _, info = sample_prior(
            TRUE,
            cfg,
            np.random.default_rng([cfg.seed, i, STREAM_PRIOR]),
            np.random.default_rng([cfg.seed, i, STREAM_PRIOR_EXTRA]),
            np.random.default_rng([cfg.seed, i, STREAM_PRIOR_REALISTIC]) if realistic else None,
        )
        out.append([*info["prior_err_xyz"], info["prior_roll_err_deg"], info["prior_pitch_err_deg"]])
    return np.array(out)


def test_realistic_prior_has_the_stated_distribution():
    e = prior_errors(query_config("realistic", queries=1))
    horizontal = np.linalg.norm(e[:, :2], axis=1)
    assert horizontal.min() >= 2.0 - 1e-9 and horizontal.max() <= 15.0 + 1e-9
    assert np.abs(e[:, 2]).max() <= 30.0 and np.abs(e[:, 2]).max() > 27.0  # uniform in +-30 m
    assert np.mean(np.abs(e[:, 2]) > 8.0) > 0.6  # most height errors beyond the old +-8 m grid
    rp = e[:, 3:].reshape(-1)
    assert np.abs(rp).max() <= 3.0 + 1e-12  # clipped at the gimbal limit
    assert 0.9 < np.std(rp) < 1.1  # N(0, 1 deg)
    assert np.mean(np.abs(rp) > 2.0) > 0.02  # the tails are there (N(0,1): 4.6 %)


def test_clean_prior_keeps_the_old_distribution():
    e = prior_errors(query_config("clean", queries=1), n=300)
    norm = np.linalg.norm(e[:, :3], axis=1)
    assert norm.min() >= 5.0 - 1e-9 and norm.max() <= 15.0 + 1e-9
    assert np.all(np.abs(e[:, 2]) <= 0.4 * norm + 1e-9)  # |dz| <= 0.37 x the norm
    assert np.abs(e[:, 3:]).max() <= 1.0


def test_clean_scenario_is_the_plain_query_config():
    assert dataclasses.replace(query_config("clean", queries=7, seed=3), scenario="clean") == QueryConfig(
        queries=7, seed=3
    )
    realistic = query_config("realistic", queries=7)
    assert realistic.scenario == "realistic" and realistic.seg_model == "structured"
    assert realistic.depth_model is not None and realistic.prior_height_m == 30.0
    assert set(SCENARIOS) == {"clean", "realistic"}


def test_settings_reach_every_knob_and_are_checked():
    cfg = query_config(
        "realistic",
        parse_settings(
            [
                "prior_height_m=10",
                "shift_xy_max_m=0.5",
                "depth_model.distortion=0.2",
                "prior_translation_m=2-5",
            ]
        ),
        queries=3,
    )
    assert cfg.prior_height_m == 10.0 and cfg.reality.shift_xy_max_m == 0.5
    assert cfg.depth_model.distortion == 0.2 and cfg.prior_translation_m == (2.0, 5.0)
    clean = set_knobs(query_config("clean", queries=1), {"depth_model.noise": [0.05, 0.08]})
    assert clean.depth_model == DepthParams(noise=(0.05, 0.08))  # starts from the realistic depth
    assert parse_value("zero-shot") == "zero-shot" and parse_value("null") is None
    assert "reality.shift_xy_max_m" in knob_names() and "prior_height_m" in knob_names()
    with pytest.raises(BenchmarkConfigError, match="unknown knob 'nope'; known: seed"):
        parse_settings(["nope=1"])
    with pytest.raises(BenchmarkConfigError, match="knob=value"):
        parse_settings(["prior_height_m"])
    with pytest.raises(BenchmarkConfigError, match="focal_mm is given twice"):  # the last one won silently
        parse_settings(["focal_mm=20", "focal_mm=28"])
    with pytest.raises(BenchmarkConfigError, match="prior_height_m"):
        query_config("realistic", {"prior_height_m": -3}, queries=1)
    # A value no check foresaw: the knob named as the caller set it (``settings``; the command prints --set).
    with pytest.raises(BenchmarkConfigError, match=r"^seg_quality=\{'a': 1\} \(settings=\.\.\.\): ") as info:
        query_config("realistic", {"seg_quality": {"a": 1}}, queries=1)
    assert as_flags(str(info.value)).startswith("seg_quality={'a': 1} (--set): ")
    with pytest.raises(BenchmarkConfigError, match="unknown scenario 'hard'"):
        query_config("hard", queries=1)
    # Beyond any map's error: a 1e9 m shift or a tree per 0.001 m2 ran one query to 18 GB (stop 50's audit)
    for knob, value in (("shift_xy_max_m", 1e9), ("tree_m2", 0.001), ("overhang_m", [0.3, 1e6])):
        with pytest.raises(BenchmarkConfigError, match=f"RealityParams.{knob} must be"):
            set_knobs(query_config("realistic", queries=1), {f"reality.{knob}": value})
    assert set_knobs(query_config("realistic", queries=1), {"reality.tree_m2": 0}).reality.tree_m2 == 0


def test_knobs_valid_only_together_are_set_together():
    # One at a time, the first would fail its own check (nominal 75 m outside 150-250 m).
    settings = parse_settings(["height_range_m=[150,250]", "nominal_height_m=200"])
    cfg = query_config("realistic", settings, queries=1)
    assert cfg.height_range_m == (150.0, 250.0) and cfg.nominal_height_m == 200.0
    with pytest.raises(BenchmarkConfigError, match="height_range_m"):
        query_config("realistic", parse_settings(["height_range_m=[150,250]"]), queries=1)


@pytest.mark.parametrize(
    "knob",
    [
        "depth_model.distortion=abc",
        "depth_model.distortion=-0.1",
        "depth_model.noise=0.3-0.1",
        "depth_model.warp_gamma=[0,1]",
        "depth_model.bleed_px=[1.5,2]",
        "depth_model.jump=true",
    ],
)
def test_depth_knobs_are_checked_where_they_are_set(knob):
    with pytest.raises(BenchmarkConfigError, match="DepthParams"):
        query_config("realistic", parse_settings([knob]), queries=1)


def depth_scene() -> tuple[np.ndarray, np.ndarray]:
    """A nadir-like depth: ground at 80 m, a block at 50 m, sky in one corner."""
    d = np.full((96, 128), 80.0)
    d[30:60, 40:90] = 50.0
    d[:10, :10] = np.inf
    labels = np.ones(d.shape, np.uint8)
    labels[30:60, 40:90] = 3
    labels[:10, :10] = 0
    return d, labels


def affine_residual(rel: np.ndarray, d: np.ndarray) -> float:
    """Relative RMS residual of the best affine fit rel ~ a d + b (what the depth cost assumes)."""
    ok = np.isfinite(rel) & np.isfinite(d)
    A = np.column_stack([d[ok], np.ones(ok.sum())])
    coef, *_ = np.linalg.lstsq(A, rel[ok], rcond=None)
    return float(np.sqrt(np.mean((A @ coef - rel[ok]) ** 2)) / np.mean(rel[ok]))


def test_realistic_depth_is_not_affine_and_keeps_sky_invalid():
    d, labels = depth_scene()
    clean = [affine_residual(simulate_depth(d, labels, np.random.default_rng(s)), d) for s in range(8)]
    real = [affine_residual(simulate_depth_realistic(d, np.random.default_rng(s)), d) for s in range(8)]
    assert np.median(real) > 2.0 * np.median(clean)
    out = simulate_depth_realistic(d, np.random.default_rng(0))
    assert np.isnan(out[:10, :10]).all() and np.isfinite(out[10:, 10:]).all() and (out[10:, 10:] > 0).all()
    # Edges bled: next to the block, the ground's relative depth moves toward the block's.
    quiet = DepthParams(noise=(0.0, 0.0), distortion=0.0, warp_gamma=(1.0, 1.0), bleed_px=(2, 2))
    q = simulate_depth_realistic(d, np.random.default_rng(1), quiet)
    far, near, beside = np.median(q[80:, 100:]), np.median(q[35:55, 50:80]), q[45, 91]
    assert abs(beside - near) < abs(far - near) * 0.6
    with pytest.raises(Exception, match="non-empty"):
        simulate_depth_realistic(np.zeros((0, 0)), np.random.default_rng(0))


def test_realistic_depth_warp_flattens_or_exaggerates_relief():
    d, _ = depth_scene()
    p = DepthParams(noise=(0.0, 0.0), distortion=0.0, bleed_px=(0, 0), warp_gamma=(0.6, 0.6))
    q = simulate_depth_realistic(d, np.random.default_rng(2), p)
    ratio = (np.median(q[80:, 100:]) - np.median(q[35:55, 50:80])) / np.median(q[80:, 100:])
    true_ratio = (80.0 - 50.0) / 80.0
    assert abs(ratio - true_ratio) > 0.02  # not the affine image of the truth


@pytest.fixture
def cli():
    from semcityloc.cli import main

    return main.main


def test_cli_scenario_set_and_sweep_with_a_report(cli, capsys, tmp_path):
    out = tmp_path / "sweep"
    args = ["--city", "generated", "--queries", "2", "--preset", "fast", "--set", "seg_model=blobs"]
    assert cli(["sweep", "--knob", "prior_height_m", "--values", "0,20", *args, "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "prior_height_m=0" in printed and "prior_height_m=20" in printed
    runs = sorted(out.iterdir())
    assert [r.name for r in runs] == ["prior_height_m=0", "prior_height_m=20"]
    cfg = json.loads((runs[1] / "run.json").read_text())
    assert cfg["sweep_knob"] == "prior_height_m" and cfg["sweep_value"] == 20
    assert cfg["query_config"]["prior_height_m"] == 20.0 and cfg["query_config"]["scenario"] == "realistic"
    assert cli(["report", *map(str, runs), "--out", str(tmp_path / "rep"), "--overlays", "0"]) == 0
    capsys.readouterr()
    table = (tmp_path / "rep" / "tables" / "sweep_prior_height_m.md").read_text()
    assert "| sweep_value |" in table and "| 0 |" in table and "| 20 |" in table
    assert (tmp_path / "rep" / "plots" / "recall_vs_prior_height_m.png").is_file()
    assert cli(["sweep", "--knob", "nope", "--values", "1", *args, "--out", str(out)]) == 2
    assert "unknown knob 'nope'" in capsys.readouterr().err
    # A sweep of another knob into the same folder: its hint named `report OUT/*`, mixing both sweeps
    assert cli(["sweep", "--knob", "seed", "--values", "1", *args, "--out", str(out)]) == 0
    printed, err = capsys.readouterr()
    assert "also holds 2 run folders of another sweep (prior_height_m=0, prior_height_m=20)" in err
    assert f"report: semcityloc report {out / 'seed=1'}" in printed and f"{out}/*" not in printed
    assert cli(["benchmark", *args, "--set", "prior_height_m=-1", "--out", str(tmp_path / "b")]) == 2
    assert "prior_height_m" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("knob", "given", "said"),
    [
        (
            "prior_roll_pitch_sigma_deg",
            ["--set", "prior_roll_pitch_sigma_deg=3"],
            "--set prior_roll_pitch_sigma_deg=3",
        ),
        ("seed", ["--seed", "9"], "--seed"),
        ("seed", ["--seed", "0"], "--seed"),  # the default, given: still a second source of the value
        ("seg_quality", ["--seg-quality", "zero-shot"], "--seg-quality"),
        ("prior_extra_m", ["--prior-extra", "10-20"], "--prior-extra"),
    ],
)
def test_sweep_refuses_what_else_sets_the_swept_knob(cli, capsys, tmp_path, knob, given, said):
    """Stop 56 audit: ``sweep --knob K --set K=3`` (or ``--knob seed --seed 9``) ran the swept values and
    dropped the other without a word."""
    argv = [
        "sweep",
        "--knob",
        knob,
        "--values",
        "1,2",
        "--city",
        "generated",
        *given,
        "--out",
        str(tmp_path / "s"),
    ]
    assert cli(argv) == 2
    err = capsys.readouterr().err
    assert f"{said}" in err and f"sets the swept knob {knob}" in err and err.count("\n") == 1
    assert not (tmp_path / "s").exists()


def test_sweep_refuses_a_value_given_twice_and_needs_its_city(cli, capsys, tmp_path):
    """Stop 56 audit: ``--values 1,1.0`` ran one value twice; sweep's help and error named ``--dataset``,
    an option sweep does not have, and showed ``--city`` as optional."""
    out = str(tmp_path / "s")
    assert cli(["sweep", "--knob", "seed", "--values", "1,1.0", "--city", "generated", "--out", out]) == 2
    assert "--values gives a value twice (1 and 1.0); give each once" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli(["sweep", "--knob", "seed", "--values", "1", "--out", out])
    assert "the following arguments are required: --city" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli(["sweep", "--help"])
    assert "--dataset" not in capsys.readouterr().out


def test_sweep_stop_after_counts_over_the_whole_sweep(cli, capsys, tmp_path):
    """Stop 56 audit: ``--stop-after 3`` localized 3 queries per value (6 for two values), while its help
    says "at most N more queries". Now N over the sweep: 2 queries, the first value's, then it stops."""
    out = tmp_path / "s"
    argv = ["sweep", "--knob", "seed", "--values", "1,2", "--city", "generated", "--queries", "2"]
    argv += ["--preset", "fast", "--set", "seg_model=blobs", "--stop-after", "2", "--out", str(out)]
    assert cli(argv) == 0
    printed = capsys.readouterr().out
    rows = {d.name: len((d / "results.csv").read_text().splitlines()) - 1 for d in out.iterdir()}
    assert rows.get("seed=1") == 2 and rows.get("seed=2", 0) == 0, rows
    assert "run again to continue" in printed


# --- the knobs' types (stop 56 audit C: H1, H2, M1, M4, L2, L3) ---


@pytest.mark.parametrize(
    ("knob", "field"),
    [
        ("depth", lambda c: c.depth),
        ("score_against_map", lambda c: c.score_against_map),
        ("lens_stated", lambda c: c.lens_stated),
        ("overhang_flat_roofs", lambda c: c.reality.overhang_flat_roofs),
    ],
)
def test_every_boolean_knob_takes_true_or_false_in_any_case_and_refuses_the_rest(knob, field):
    """Stop 56 audit: ``--set depth=False`` ran with depth (``bool('False')`` is True), and
    ``overhang_flat_roofs=False`` was kept as the text 'False', which ``build_reality`` took for True."""
    for text, want in (
        ("False", False),
        ("TRUE", True),
        ("no", False),
        ("yes", True),
        ("0", False),
        ("1", True),
    ):
        cfg = query_config("realistic", parse_settings([f"{knob}={text}"]), queries=1)
        assert field(cfg) is want, (knob, text)
    for text in ("maybe", "2", "0.5", "null"):
        with pytest.raises(BenchmarkConfigError, match=rf"{knob} must be true or false, got ") as info:
            query_config("realistic", parse_settings([f"{knob}={text}"]), queries=1)
        assert "\n" not in str(info.value)


def test_the_python_api_refuses_a_boolean_given_as_other_text():
    """The same rule for a library caller: ``QueryConfig(depth="no")`` was depth on."""
    from semcityloc.benchmark.reality import RealityParams

    assert (
        QueryConfig(depth="no").depth is False
        and QueryConfig(score_against_map="False").score_against_map is False
    )
    assert RealityParams(overhang_flat_roofs=np.False_).overhang_flat_roofs is False
    for bad in ({"depth": "maybe"}, {"score_against_map": 2}, {"lens_stated": None}):
        with pytest.raises(BenchmarkConfigError, match="must be true or false"):
            QueryConfig(**bad)
    with pytest.raises(BenchmarkConfigError, match="RealityParams.overhang_flat_roofs must be true or false"):
        RealityParams(overhang_flat_roofs="maybe")


@pytest.mark.parametrize(
    "setting",
    [
        "shift_xy_max_m=abc",
        "shift_xy_max_m=nan",
        "shift_xy_max_m=inf",
        "roof_change_fraction=nan",
        "roof_structure_m2=nan",
        "reality.margin_m=true",
        'tree_height_m=[4,"x"]',
    ],
)
def test_a_reality_knob_of_the_wrong_type_says_the_type_wanted_in_one_line(setting):
    """Stop 56 audit: ``--set shift_xy_max_m=abc`` said ``'<=' not supported between instances of 'float'
    and 'str'``; the lower-case ``nan`` / ``inf`` users type stayed text and failed so too."""
    knob = setting.partition("=")[0].rpartition(".")[2]
    with pytest.raises(
        BenchmarkConfigError,
        match=rf"^RealityParams\.{knob} must be a (finite number|\(low, high\) pair of numbers), got ",
    ) as info:
        query_config("realistic", parse_settings([setting]), queries=1)
    assert "not supported" not in str(info.value)


def test_every_reality_field_has_its_type_checked():
    """``RealityParams`` checks each field's type by its annotation: a new field of another type would go
    unchecked."""
    from semcityloc.benchmark.reality import RealityParams

    kinds = {f.type for f in dataclasses.fields(RealityParams)}
    assert kinds <= {"float", "bool", "str", "tuple[float, float]", "tuple[float, float] | None"}


def test_queries_and_scenario_are_no_knobs_and_the_option_that_sets_them_is_named():
    """Stop 56 audit: ``--set scenario=clean`` labelled a realistic run clean, ``--set queries=4`` overrode
    ``--queries 3`` without a word: ``resolve_knob`` took every field, ``knob_names`` listed fewer."""
    from semcityloc.benchmark.scenario import resolve_knob

    for name, flag in (("queries", "--queries"), ("scenario", "--scenario")):
        with pytest.raises(BenchmarkConfigError, match=f"^{name} is no knob of settings=") as info:
            parse_settings([f"{name}=4"])
        assert as_flags(str(info.value)) == f"{name} is no knob of --set: give it as {flag}"
        with pytest.raises(BenchmarkConfigError):
            query_config("realistic", {name: 4}, queries=1)
    for name in knob_names():  # one list: every name listed resolves, and by its own name when unambiguous
        assert resolve_knob(name)[1] == name.rpartition(".")[2]
    assert resolve_knob("noise") == ("depth_model", "noise")


@pytest.mark.parametrize(
    ("setting", "said"),
    [
        ("focal_mm=0", "focal_mm must be positive, got 0"),
        ("prior_yaw_deg=1000", "prior_yaw_deg must be in [0, 180], got 1000"),
        ("oblique_fraction=2", "oblique_fraction must be in [0, 1], got 2"),
        ("min_building_fraction=1", "min_building_fraction must be in [0, 1), got 1"),
        ("max_roll_deg=50", "max_roll_deg must be in [0, 45], got 50"),
        ("prior_roll_pitch_deg=-1", "prior_roll_pitch_deg must be in [0, 45], got -1"),
        ("seed=-1", "seed must be >= 0, got -1"),
        ("width=100000", "width must be in [16, 8192] pixels, got 100000"),
        ("height=8193", "height must be in [16, 8192] pixels, got 8193"),
        ("width=15", "width must be in [16, 8192] pixels, got 15"),
    ],
)
def test_a_query_knob_out_of_range_is_named_alone(setting, said):
    """Stop 56 audit: ``--set focal_mm=0`` said ``prior_roll_pitch_deg must be in [0, 45] and focal_mm
    positive``, naming a knob not set; ``width=100000`` was accepted (only 16 was checked)."""
    with pytest.raises(BenchmarkConfigError) as info:
        query_config("realistic", parse_settings([setting]), queries=1)
    assert str(info.value) == said


def test_cli_names_stop_after_and_takes_a_negative_looking_prior_extra(cli, capsys, tmp_path):
    """Stop 56 audit: ``--stop-after -1`` said ``limit must be >= 0`` (the Python name); ``--prior-extra
    -5-10`` got argparse's ``expected one argument``."""
    base = ["benchmark", "--city", "generated", "--queries", "1", "--out", str(tmp_path / "o")]
    assert cli([*base, "--stop-after", "-1"]) == 2
    assert capsys.readouterr().err == "semcityloc: error: --stop-after must be >= 0, got -1\n"
    for given in (["--prior-extra", "-5-10"], ["--prior-extra=-5-10"]):
        assert cli([*base, *given]) == 2
        err = capsys.readouterr().err
        assert (
            err
            == "semcityloc: error: --prior-extra A-B needs 0 <= A <= B, got '-5-10': no negative distances\n"
        )
    assert not (tmp_path / "o").exists()


def test_sweep_of_queries_sets_them_as_queries_does(cli, capsys, tmp_path):
    """``queries`` is no ``--set`` knob, but ``sweep --knob queries`` still sweeps it (as ``--queries``)."""
    out = tmp_path / "s"
    argv = ["sweep", "--knob", "queries", "--values", "1,2", "--city", "generated", "--stop-after", "0"]
    assert cli([*argv, "--out", str(out)]) == 0
    capsys.readouterr()
    for n in (1, 2):
        cfg = json.loads((out / f"queries={n}" / "run.json").read_text())
        assert cfg["query_config"]["queries"] == n and cfg["query_config"]["scenario"] == "realistic"


def test_a_negative_looking_offset_reaches_its_option(tmp_path):
    """``run --offset -3.5,12,0`` (a model's frame east of the CRS origin) got argparse's ``expected one
    argument``: the value is joined to its option as ``--prior-extra``'s is (``joined_dash_values``)."""
    from semcityloc.cli.main import build_parser, joined_dash_values

    argv = ["run", str(tmp_path), "--city", "c.gml", "--masks", "m", "--offset", "-3.5,12,0"]
    assert joined_dash_values(argv)[-1] == "--offset=-3.5,12,0"
    assert build_parser().parse_args(joined_dash_values(argv)).offset == "-3.5,12,0"
    dji = ["dataset", "dji-prior", "x.JPG", "--crs", "EPSG:32649", "--offset", "-1,2,3"]
    assert build_parser().parse_args(joined_dash_values(dji)).offset == "-1,2,3"


@pytest.mark.parametrize(
    "settings",
    [
        {"noise": (True, 2)},
        {"noise": "12"},
        {"bleed_px": (False, True)},
        {"distortion": True},
        {"jump": "0.1"},
    ],
)
def test_depth_knobs_take_numbers_not_bools_or_text(settings):
    """``DepthParams`` took ``True`` as 1 and the text ``"12"`` as the pair (1, 2) (stop 56): a number test
    shared with ``RealityParams`` (``errors.finite_number``)."""
    name = next(iter(settings))
    with pytest.raises(BenchmarkConfigError, match=f"DepthParams.{name} must be"):
        DepthParams(**settings)
