"""``--executor ray`` (``benchmark.ray_executor``): rows identical to the serial run, a killed worker's
query retried once, then recorded as failed. Skipped when the ``[ray]`` extra is absent (``make test``
installs it)."""

from __future__ import annotations

import functools
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from semcityloc.benchmark.queries import QueryConfig, QuerySimulator
from semcityloc.benchmark.ray_executor import run_token
from semcityloc.benchmark.results import FAILED, TIMING_COLUMNS, read_results
from semcityloc.benchmark.run import run_benchmark
from semcityloc.benchmark.spec import BenchmarkSpec
from semcityloc.cli.main import main
from semcityloc.errors import BenchmarkError

ray = pytest.importorskip("ray", reason="the [ray] extra is not installed: pip install 'semcityloc[ray]'")

QUERIES = QueryConfig(queries=6, seed=0, width=256, height=192)


class CrashingSimulator:
    """The query simulator, except that making query 1 kills its worker process the first time and query
    2 kills it every time (``os._exit``: the process dies as under the OOM killer, no exception)."""

    def __init__(self, marker_dir: str, map_model, config, reality_model=None):
        self.marker = Path(marker_dir) / "q1_died"
        self.inner = QuerySimulator(map_model, config, reality_model)

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def query(self, index: int):
        if index == 2 or (index == 1 and not self.marker.exists()):
            self.marker.touch()
            os._exit(1)
        return self.inner.query(index)


# Ray's workers cannot import this test module: ship its code with the task.
ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])


@pytest.fixture(scope="module")
def ray_runtime():
    """One small local runtime for the module (start-up takes seconds); shut down at the end."""
    ray.init(
        address="local",
        num_cpus=2,
        include_dashboard=False,
        log_to_driver=False,
        object_store_memory=200 * 1024 * 1024,
    )
    yield
    ray.shutdown()


@pytest.fixture(scope="module")
def serial_rows(tmp_path_factory):
    out = tmp_path_factory.mktemp("serial")
    outcome = run_benchmark(BenchmarkSpec("generated", QUERIES, preset="fast"), out, progress=False)
    return {r["query_id"]: _untimed(r) for r in outcome.rows}


def _untimed(row: dict[str, str]) -> dict[str, str]:
    return {k: v for k, v in row.items() if k not in TIMING_COLUMNS}


@pytest.mark.slow
def test_ray_rows_are_the_serial_rows(ray_runtime, serial_rows, tmp_path):
    spec = BenchmarkSpec("generated", QUERIES, preset="fast")
    outcome = run_benchmark(spec, tmp_path / "ray", workers=2, progress=False, executor="ray")
    assert outcome.complete and outcome.new_rows == 6
    assert {r["query_id"]: _untimed(r) for r in outcome.rows} == serial_rows
    assert any(r["status"] == "localized" for r in outcome.rows)


@pytest.mark.slow
def test_a_killed_worker_is_retried_once_then_the_query_is_failed(ray_runtime, serial_rows, tmp_path):
    factory = functools.partial(CrashingSimulator, str(tmp_path))
    spec = BenchmarkSpec("generated", QUERIES, preset="fast", simulator_factory=factory)
    out = tmp_path / "ray"
    outcome = run_benchmark(spec, out, workers=2, progress=False, executor="ray")
    rows = {r["query_id"]: r for r in read_results(out / "results.csv")}
    assert outcome.complete and len(rows) == 6
    assert (tmp_path / "q1_died").exists()  # query 1 did kill its first worker
    assert _untimed(rows["q0001"]) == serial_rows["q0001"]  # ... and was done by the next
    assert rows["q0002"]["status"] == FAILED
    assert rows["q0002"]["reason"].startswith("worker died 2 times")
    for qid in ("q0000", "q0003", "q0004", "q0005"):
        assert _untimed(rows[qid]) == serial_rows[qid]
    assert outcome.summary["not_localized_reasons"].get(rows["q0002"]["reason"]) == 1
    assert rows["q0002"]["err_xyz_m"] == "inf"  # a simulated query has a true pose: a miss of the recall
    assert outcome.summary["queries"] == 6 and outcome.summary["with_ground_truth"] == 6
    again = run_benchmark(spec, out, workers=2, progress=False, executor="ray")
    assert again.new_rows == 0  # a failed query has its row: a resumed run does not try it again


def test_executor_options_are_checked(tmp_path, capsys):
    spec = BenchmarkSpec("generated", QUERIES, preset="fast")
    with pytest.raises(BenchmarkError, match="unknown executor 'dask'"):
        run_benchmark(spec, tmp_path / "x", executor="dask")
    args = ["benchmark", "--city", "generated", "--queries", "1", "--out", str(tmp_path / "y")]
    assert main([*args, "--ray-address", "auto"]) == 2
    assert "--ray-address needs --executor ray" in capsys.readouterr().err
    assert main([*args, "--executor", "ray", "--ray-address", "head:http"]) == 2
    assert "expected host:port" in capsys.readouterr().err
    assert not (tmp_path / "y").exists()  # refused before the run began


def test_a_run_token_is_set_for_the_block_unless_the_user_set_one(monkeypatch):
    monkeypatch.delenv("RAY_AUTH_TOKEN", raising=False)
    monkeypatch.delenv("RAY_AUTH_TOKEN_PATH", raising=False)
    with run_token():
        first = os.environ["RAY_AUTH_TOKEN"]
        assert len(first) == 64 and int(first, 16) >= 0
    assert "RAY_AUTH_TOKEN" not in os.environ
    with run_token():
        assert os.environ["RAY_AUTH_TOKEN"] != first  # a fresh one per run
    monkeypatch.setenv("RAY_AUTH_TOKEN_PATH", "/somewhere/token")
    with run_token():
        assert "RAY_AUTH_TOKEN" not in os.environ  # the user's own token file is used
    monkeypatch.delenv("RAY_AUTH_TOKEN_PATH")
    monkeypatch.setenv("RAY_AUTH_TOKEN", "mine")
    with run_token():
        assert os.environ["RAY_AUTH_TOKEN"] == "mine"
    assert os.environ["RAY_AUTH_TOKEN"] == "mine"


@pytest.mark.slow
def test_a_local_ray_run_leaves_no_token_in_the_users_home(tmp_path):
    """Ray's local runtimes write ``~/.ray/auth_token`` by default; a run's own runtime does not."""
    home = tmp_path / "home"
    home.mkdir()
    env = {**os.environ, "HOME": str(home)}
    env.pop("RAY_AUTH_TOKEN", None)
    env.pop("RAY_AUTH_TOKEN_PATH", None)
    env.setdefault("SEMCITYLOC_CACHE", str(Path.home() / ".cache"))  # the generated city, already made
    args = ["benchmark", "--city", "generated", "--queries", "2", "--preset", "fast", "--workers", "1"]
    args += ["--executor", "ray", "--out", str(tmp_path / "out")]
    code = "import sys; from semcityloc.cli.main import main; sys.exit(main(sys.argv[1:]))"
    done = subprocess.run([sys.executable, "-c", code, *args], env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    assert (tmp_path / "out" / "summary.json").is_file()
    assert not (home / ".ray" / "auth_token").exists()


# A run's driver (``run_ray`` with a local runtime) whose two workers write their pid, then wait.
_DRIVER = """
import os, sys, time
from semcityloc.benchmark.ray_executor import run_ray

class Waiting:
    def __init__(self, folder):
        self.folder = folder

    def run(self, index):
        with open(os.path.join(self.folder, f"{index}.tmp"), "w") as fh:
            fh.write(str(os.getpid()))
        os.replace(os.path.join(self.folder, f"{index}.tmp"), os.path.join(self.folder, f"{index}.pid"))
        time.sleep(600)

for row in run_ray([0, 1], 2, Waiting, (sys.argv[1],)):
    pass
"""


_AGENTS = ("ray::DashboardA", "ray::RuntimeEnv")  # their names as /proc shows them (15 characters)


def _descendants(pid: int) -> dict[int, str]:
    """The processes below ``pid`` (``/proc``), with their names."""
    parents: dict[int, list[int]] = {}
    for entry in filter(str.isdigit, os.listdir("/proc")):
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
        except OSError:
            continue
        parents.setdefault(int(stat[stat.rfind(")") + 2 :].split()[1]), []).append(int(entry))
    out, todo = {}, [pid]
    while todo:
        for child in parents.get(todo.pop(), []):
            out[child] = _name(child)
            todo.append(child)
    return out


def _name(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/comm").read_text().strip()
    except OSError:
        return "?"


def _alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat[stat.rfind(")") + 2] != "Z"


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM], ids=["SIGKILL", "SIGTERM"])
def test_ray_workers_end_with_the_run_that_started_them(tmp_path, sig):
    """Why the Ray workers need no ``_die_with_parent`` of their own (``ray_executor`` docstring): they are
    the raylet's children, not the driver's, and Ray ends them with the driver. SIGKILL: Ray's head
    processes die with the driver (Ray starts them with ``PR_SET_PDEATHSIG``) and the workers with the
    raylet, within seconds; SIGTERM: Ray's own handler exits the driver, whose ``ray.shutdown`` (``run_ray``'s
    ``finally``, Ray's ``atexit``) ends every process it started."""
    driver = subprocess.Popen([sys.executable, "-c", _DRIVER, str(tmp_path)], stderr=subprocess.DEVNULL)
    workers: list[int] = []
    try:
        deadline = time.monotonic() + 120
        while len(workers) < 2 and time.monotonic() < deadline:
            workers = [int(p.read_text()) for p in tmp_path.glob("*.pid")]
            time.sleep(0.1)
        assert len(workers) == 2 and all(map(_alive, workers)), "the Ray workers did not start"
        started = _descendants(driver.pid)
        assert set(workers) <= set(started) and "raylet" in started.values()
        driver.send_signal(sig)
        driver.wait(60)
        # Every process Ray started: the workers (each holds the city), its head, its monitors; but after
        # SIGKILL Ray's two agents (the dashboard's and the runtime environments') end by themselves
        # about a minute later, once they notice the raylet gone.
        ends = [p for p, name in started.items() if sig == signal.SIGTERM or not name.startswith(_AGENTS)]
        deadline = time.monotonic() + 30
        while any(map(_alive, ends)) and time.monotonic() < deadline:
            time.sleep(0.2)
        left = {p: started[p] for p in ends if _alive(p)}
        assert not left, f"outlived the run: {left}"
    finally:
        driver.kill()
        for pid in workers:
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
