"""Coverage-guided fuzzing of one reader with atheris (libFuzzer), the optional extra ``semcityloc[fuzz]``.

Run as ``python tests/fuzz_atheris.py TARGET RUNS COUNTS.json`` (``fuzz_run.py --engine atheris`` runs it
once per target, in its own process: libFuzzer ends the process when its runs are done). Inputs start
from the target's seeds (``fuzzing.py``) and are mutated by the same structure-aware mutators, libFuzzer
keeping the ones that reach new code; the outcome counts are written to COUNTS.json after every input and
a crash (any exception but a typed error) stops the run with libFuzzer's crash report.
"""

from __future__ import annotations

import json
import random
import sys
import tempfile
from pathlib import Path

import atheris

with atheris.instrument_imports(include=["semcityloc"]):  # coverage of the library's code only
    from fuzzing import CRASH, TYPED, VALID, Fuzzer


def main() -> None:
    target, runs, counts_file = sys.argv[1], int(sys.argv[2]), Path(sys.argv[3])
    work = Path(tempfile.mkdtemp(prefix=f"semcityloc-atheris-{target}-"))
    fuzzer = Fuzzer(target, work)
    name = fuzzer.seeds[0][0]
    corpus = work / "corpus"
    corpus.mkdir()
    for i, (_, data) in enumerate(fuzzer.seeds):
        (corpus / f"seed{i}").write_bytes(data)
    counts = {TYPED: 0, VALID: 0, CRASH: 0}

    def test_one(data: bytes) -> None:
        outcome, exc = fuzzer.run(name, data)
        counts[outcome] += 1
        counts_file.write_text(json.dumps(counts))
        if outcome == CRASH:
            raise exc

    def mutate(data: bytes, max_size: int, seed: int) -> bytes:
        rng = random.Random(seed)
        return fuzzer.target.mutate(rng, data or rng.choice(fuzzer.seeds)[1])[:max_size]

    max_len = max(len(d) for _, d in fuzzer.seeds) * 2
    atheris.Setup(
        [sys.argv[0], f"-runs={runs}", f"-max_len={max_len}", "-timeout=10", "-seed=1", str(corpus)],
        test_one,
        custom_mutator=mutate,
    )
    atheris.Fuzz()


if __name__ == "__main__":
    main()
