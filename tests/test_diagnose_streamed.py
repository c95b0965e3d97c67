"""Records read in chunks (``lj.diagnose(..., streamed=N)``): every statistic accumulated chunk
by chunk with the filters' states carried, against each record read in one chunk
(``streamed=False``: one recursion over the padded record, products of whole designs): the
same verdict and stack, the confidence within 0.02 (the issue's agreement; measured within
2e-13 on 43 development records). Chunks of 1024 samples, shorter than the records, carry the
states across 2 to 13 chunk edges. The chunked kernels against one pass at 1e-8 to 1e-12:
test_diagnose_kernels.py."""

import diagnosis_blind as blind  # benchmarks/ (tests/conftest.py)
import numpy as np
import pytest

import lionjax as lj

#: Samples per chunk of the chunked diagnoses, at least.
CHUNK = 1024
#: Largest difference of the confidences in chunks and in one chunk.
CONFIDENCE_TOL = 0.02


def _agree(a: lj.diagnosis.Diagnosis, b: lj.diagnosis.Diagnosis) -> None:
    assert (b.verdict, b.stack) == (a.verdict, a.stack)
    assert abs(b.confidence - a.confidence) <= CONFIDENCE_TOL
    assert b.to_json()["settings"] == a.to_json()["settings"]


@pytest.mark.slow
@pytest.mark.parametrize(
    "cls,source",
    [("coulomb_friction", "twin"), ("flexible_mode", "scipy"), ("cogging", "twin")],
)
def test_diagnosis_in_chunks_agrees_with_one_chunk(cls, source):
    """Whole diagnoses of held-out-style records (friction that sticks, a flexible mode, a
    force periodic in position: the look-alikes' screen) read in chunks against each record in
    one chunk: the longest power-of-two chunk of at least 1024 samples that cuts the shorter
    record into three chunks or more (4096 of 14 050 samples, 2048 of 8086, 1024 of 2581), so
    that every record crosses at least two chunk edges."""
    i = blind.CLASSES.index(cls)
    seed = 300_000_000 + 1000 * i + blind.SOURCES.index(source)
    tr, va, _ = blind.make_case(cls, seed, source=source)
    n = min(tr.n_samples, va.n_samples)
    chunk = max(CHUNK, 1 << int(np.log2(n / 3)))
    assert n > 2 * chunk  # three chunks or more
    _agree(lj.diagnose(tr, va, streamed=False), lj.diagnose(tr, va, streamed=chunk))


def test_streamed_argument_is_checked():
    """``streamed`` is True, False, None or a chunk length of at least 16 samples; anything
    else is refused before any fit, naming the argument."""
    t = np.arange(2000) * 1e-3
    rec = lj.Record(0.01 * np.sin(5 * t), np.cos(5 * t), 1e-3)
    for bad in ("yes", 8, 2.5):
        with pytest.raises(lj.InputError, match="streamed must be True, False, None or a chunk"):
            lj.diagnose(rec, streamed=bad)


def test_cli_streamed_flag(tmp_path):
    """``lionjax diagnose --streamed on`` is parsed and diagnoses (the JSON's verdict and stack
    equal the call's in one chunk, confidence within 0.02; a record shorter than the default
    chunk of 2¹⁶ samples is read in one either way); a bad value is refused by the parser."""
    import json

    from lionjax.cli import main

    tr, va, _ = blind.make_case("offset", 300_002_000, source="twin")
    paths = []
    for nm, rec in (("train", tr), ("valid", va)):
        paths.append(tmp_path / f"{nm}.npz")
        lj.save_record(paths[-1], rec)
    out = tmp_path / "d.json"
    argv = ["diagnose", str(paths[0]), "--validate", str(paths[1]), "--json", str(out)]
    assert main([*argv, "--streamed", "on"]) == 0
    got = json.loads(out.read_text())
    ref = lj.diagnose(tr, va, streamed=False)
    assert (got["verdict"], got["stack"]) == (ref.verdict, list(ref.stack))
    assert abs(got["confidence"] - ref.confidence) <= CONFIDENCE_TOL
    with pytest.raises(SystemExit):
        main([*argv, "--streamed", "yes"])
