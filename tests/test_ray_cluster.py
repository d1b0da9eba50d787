"""``--ray-address``: a running Ray cluster is joined (rows identical to the local run's); an address where
nothing answers is refused in one line at once (not after Ray's minutes of retries), a cluster that asks
for Ray's token in one line that names ``RAY_AUTH_MODE=token`` (not Ray's traceback); without an address
a runtime of its own is started even when a cluster runs on the machine. The cluster runs under a HOME
of its own (Ray keeps its token there). Skipped when the ``[ray]`` extra is absent (``make test``
installs it)."""

from __future__ import annotations

import csv
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from semcityloc.benchmark.ray_executor import check_address, host_port
from semcityloc.benchmark.results import TIMING_COLUMNS
from semcityloc.citymodel.generator import default_city_path
from semcityloc.cli.main import main
from semcityloc.errors import BenchmarkError

pytest.importorskip("ray", reason="the [ray] extra is not installed: pip install 'semcityloc[ray]'")

BIN = Path(sys.executable).parent
RUN = ["benchmark", "--city", "generated", "--queries", "3", "--preset", "fast"]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _rows(out: Path) -> list[dict[str, str]]:
    """The rows of a run without their timings, by query (a pool writes them in the order they finish)."""
    with open(out / "results.csv", newline="") as f:
        rows = [{k: v for k, v in r.items() if k not in TIMING_COLUMNS} for r in csv.DictReader(f)]
    return sorted(rows, key=lambda r: r["query_id"])


def test_cluster_addresses_are_parsed():
    assert host_port("10.0.0.5:6379") == ("10.0.0.5", 6379)
    assert host_port("ray://head.example:10001") == ("head.example", 10001)
    assert host_port("[::1]:6379") == ("::1", 6379)
    assert host_port("auto") is None and host_port("local") is None
    for wrong in ("10.0.0.5:http", "garbage", ":6379", "http://head:6379", "ray://head"):
        with pytest.raises(
            BenchmarkError, match=r"expected host:port \(e.g. 10.0.0.5:6379\), ray://host:port"
        ):
            host_port(wrong)


def test_a_ray_client_address_without_the_client_names_what_to_install(monkeypatch):
    """Stop 56's audit: ``ray://`` (which --help offers) ended in Ray's traceback `Ray Client requires pip
    package ray[client]`; the [ray] extra does not install it."""
    monkeypatch.setitem(sys.modules, "grpc", None)  # the client's dependency, absent
    with pytest.raises(BenchmarkError, match=r"needs Ray's client.*pip install 'ray\[client\]'"):
        check_address("ray://head.example:10001")
    assert check_address("head.example:6379") == ("head.example", 6379)


def _no_init(*args, **kwargs):
    raise AssertionError("ray.init was called: Ray retries an address where nothing answers for minutes")


def test_a_malformed_address_or_auto_at_a_stale_address_is_refused_before_ray(tmp_path, capsys, monkeypatch):
    """Stop 56's audit: `--ray-address garbage` ended in Ray's `ValueError: Invalid address format`
    traceback, and `auto` with a `ray_current_cluster` file left by a `ray start` long gone waited minutes
    for that address: both refused in one line, before ``ray.init``."""
    import ray

    monkeypatch.setattr(ray, "init", _no_init)
    run = [*RUN, "--executor", "ray", "--out", str(tmp_path / "out")]
    assert main([*run, "--ray-address", "garbage"]) == 2
    err = capsys.readouterr().err
    assert "--ray-address garbage: expected host:port" in err and "Traceback" not in err
    port = _free_port()
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    monkeypatch.setenv("RAY_TMPDIR", str(tmp_path))  # Ray's temporary folder, where `ray start` notes it
    # auto prefers a head running on this machine (another test's, another user's) to the file: none here.
    monkeypatch.setattr(ray._private.services, "find_gcs_addresses", frozenset)
    (tmp_path / "ray").mkdir()
    (tmp_path / "ray" / "ray_current_cluster").write_text(f"127.0.0.1:{port}")
    assert main([*run, "--ray-address", "auto"]) == 2
    err = capsys.readouterr().err
    assert f":{port}, the address Ray found for auto" in err  # Ray names 127.0.0.1 by the machine's address
    assert "`ray stop` clears it" in err and "Traceback" not in err


def test_rays_own_refusal_of_an_address_is_one_line(tmp_path, capsys, monkeypatch):
    """What Ray raises from ``ray.init`` once something answers at the address (a ``ValueError`` of an
    address Ray reads otherwise, a failed connection) is one line, not Ray's traceback."""
    import ray

    def invalid(*args, **kwargs):
        raise ValueError("Invalid address format: 127.0.0.1\nmore of Ray's words")

    monkeypatch.setattr(ray, "init", invalid)
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        address = f"127.0.0.1:{server.getsockname()[1]}"
        code = main([*RUN, "--executor", "ray", "--ray-address", address, "--out", str(tmp_path)])
    assert code == 2
    err = capsys.readouterr().err
    assert f"--ray-address {address}: Invalid address format: 127.0.0.1; " in err
    assert "Traceback" not in err and "more of Ray's words" not in err


def test_an_address_where_nothing_answers_is_refused_in_one_line(tmp_path, capsys, monkeypatch):
    import ray

    # "At once" without a clock: the refusal comes from the connection check, before ray.init (where Ray
    # would retry for minutes); a call to ray.init fails the test.
    monkeypatch.setattr(ray, "init", _no_init)
    port = _free_port()
    code = main([*RUN, "--executor", "ray", "--ray-address", f"127.0.0.1:{port}", "--out", str(tmp_path)])
    assert code == 2
    err = capsys.readouterr().err
    assert f"no Ray cluster answers at 127.0.0.1:{port}" in err and "ray start --head" in err
    assert "Traceback" not in err


def _ray_env(home: Path, **extra: str) -> dict[str, str]:
    """This environment without Ray's variables, with ``home`` as HOME (where Ray keeps its token)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("RAY_")}
    return {**env, "HOME": str(home), **extra}


@pytest.mark.slow
def test_a_running_cluster_is_joined_by_its_address(tmp_path):
    """A head with Ray's token authentication (what ``ray start --head`` does wherever a local Ray runtime
    has run before: it wrote ``~/.ray/auth_token``): joined without the token mode, a one-line hint;
    with ``RAY_AUTH_MODE=token``, the local run's rows."""
    home = tmp_path / "home"
    home.mkdir()
    subprocess.run(
        [str(BIN / "ray"), "get-auth-token", "--generate"],
        env=_ray_env(home),
        check=True,
        capture_output=True,
    )
    assert (home / ".ray" / "auth_token").is_file()
    city = str(default_city_path(lod=2))  # not regenerated under the new HOME
    run = ["benchmark", "--city", city, *RUN[3:]]
    port = _free_port()
    head = subprocess.Popen(
        [
            str(BIN / "ray"),
            "start",
            "--head",
            "--block",
            f"--port={port}",
            "--node-ip-address=127.0.0.1",
            "--num-cpus=2",
            "--include-dashboard=false",
            "--disable-usage-stats",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env=_ray_env(home),
    )
    token = _ray_env(home, RAY_AUTH_MODE="token")

    def semcityloc(*args: str, env: dict[str, str]) -> subprocess.CompletedProcess:
        return subprocess.run(
            [str(BIN / "semcityloc"), *run, "--workers", "2", *args],
            capture_output=True,
            text=True,
            env=env,
            timeout=600,
        )

    try:
        deadline = time.monotonic() + 120.0
        while True:  # up when `ray status` sees the node (the GCS port answers before the node registers)
            status = subprocess.run(
                [str(BIN / "ray"), "status", f"--address=127.0.0.1:{port}"],
                capture_output=True,
                text=True,
                env=token,
                timeout=60,
            )
            if status.returncode == 0:
                break
            assert head.poll() is None, "ray start --head exited"
            assert time.monotonic() < deadline, (
                f"the Ray head did not come up within 120 s: {status.stderr[-800:]}"
            )
            time.sleep(1.0)
        address = ["--executor", "ray", "--ray-address", f"127.0.0.1:{port}"]
        refused = semcityloc(*address, "--out", str(tmp_path / "refused"), env=_ray_env(home))
        assert refused.returncode == 2 and "set RAY_AUTH_MODE=token" in refused.stderr, refused.stderr[-2000:]
        assert "Traceback" not in refused.stderr
        joined = semcityloc(*address, "--out", str(tmp_path / "ray"), env=token)
        assert joined.returncode == 0, joined.stderr[-2000:]
        # Without an address a runtime of its own is started, the machine's cluster notwithstanding.
        own = semcityloc("--executor", "ray", "--out", str(tmp_path / "own"), env=_ray_env(home))
        assert own.returncode == 0, own.stderr[-2000:]
    finally:
        head.terminate()
        try:
            head.wait(timeout=60)
        except subprocess.TimeoutExpired:
            head.kill()
    assert main([*run, "--out", str(tmp_path / "local")]) == 0
    local = _rows(tmp_path / "local")
    assert _rows(tmp_path / "ray") == local and _rows(tmp_path / "own") == local and len(local) == 3
