"""Benchmark the CityGML reader: parse time, throughput and peak memory for one city file.

Usage: ``python benchmarks/bench_citymodel.py [--city PATH] [--repeat N]``. The default city is Den Haag's
24 MB CityGML 1.0 file, unzipped from ``../shared/data/denhaag_lod2/DenHaag_01.zip`` to a temporary
directory; when that data is absent the script says so and exits 0. ``--city`` takes a CityGML file
(``.gml``/``.xml``/``.gz``) or a zip holding one.

Prints one JSON line: ``file, mb, parse_s, mb_per_s, peak_rss_mb, baseline_rss_mb, triangles, buildings``.
``parse_s`` is the fastest of ``--repeat`` runs of ``read_citygml`` (XML streaming + triangulation + mesh
build), without interpreter start-up and imports. Memory is measured in a fresh child process:
``peak_rss_mb`` is the child's ``resource.getrusage(RUSAGE_SELF).ru_maxrss`` after the reads, and
``baseline_rss_mb`` is the same figure after the imports but before the first read (Python + numpy + lxml +
pyproj), so ``peak_rss_mb - baseline_rss_mb`` is what reading the city cost.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DEFAULT_ZIP = REPO.parent / "shared" / "data" / "denhaag_lod2" / "DenHaag_01.zip"
DEFAULT_MEMBER = "DenHaag/DenHaag_01.xml"


def _child(path: str, repeat: int) -> None:
    """Runs in the child process: read the city, print the measurements as JSON."""
    import resource
    import time

    from semcityloc.citymodel.citygml import read_citygml

    baseline = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    best = float("inf")
    model = None
    for _ in range(repeat):
        model = None  # drop the previous model before the next read
        t0 = time.perf_counter()
        model = read_citygml(path)
        best = min(best, time.perf_counter() - t0)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(
        json.dumps(
            {
                "parse_s": round(best, 3),
                "peak_rss_mb": round(peak, 1),
                "baseline_rss_mb": round(baseline, 1),
                "triangles": model.num_triangles,
                "buildings": model.num_buildings,
            }
        )
    )


def _extract(zip_path: Path, member: str | None, into: Path) -> Path:
    with zipfile.ZipFile(zip_path) as z:
        if member is None:
            names = [n for n in z.namelist() if n.endswith((".gml", ".xml")) and not n.startswith("__MACOSX")]
            if not names:
                raise SystemExit(f"{zip_path}: no .gml/.xml file inside")
            member = names[0]
        return Path(z.extract(member, into))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--city", type=Path, help="CityGML file (or zip holding one); default: Den Haag")
    parser.add_argument("--repeat", type=int, default=1, help="reads in the child; the fastest is reported")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        _child(args.child, max(1, args.repeat))
        return 0

    with tempfile.TemporaryDirectory(prefix="semcityloc-bench-") as tmp:
        if args.city is None:
            if not DEFAULT_ZIP.exists():
                print(f"benchmark data not found: {DEFAULT_ZIP} (../shared/data is absent): nothing to do")
                return 0
            city = _extract(DEFAULT_ZIP, DEFAULT_MEMBER, Path(tmp))
        elif args.city.suffix.lower() == ".zip":
            city = _extract(args.city, None, Path(tmp))
        else:
            city = args.city
        if not city.exists():
            print(f"city file not found: {city}", file=sys.stderr)
            return 2
        proc = subprocess.run(
            [sys.executable, __file__, "--child", str(city), "--repeat", str(args.repeat)],
            capture_output=True,
            text=True,
        )
        if proc.returncode != 0:
            print(proc.stderr.strip(), file=sys.stderr)
            return proc.returncode
        result = json.loads(proc.stdout.strip().splitlines()[-1])
        mb = city.stat().st_size / 1e6
        out = {
            "file": str(args.city or f"{DEFAULT_ZIP.name}:{DEFAULT_MEMBER}"),
            "mb": round(mb, 2),
            "parse_s": result["parse_s"],
            "mb_per_s": round(mb / result["parse_s"], 2) if result["parse_s"] > 0 else None,
            "peak_rss_mb": result["peak_rss_mb"],
            "baseline_rss_mb": result["baseline_rss_mb"],
            "triangles": result["triangles"],
            "buildings": result["buildings"],
        }
        print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
