"""Motion files as every door reads them: a .npy's header is checked before its data (the library, the command line
and HTTP run the same check)."""

from __future__ import annotations

import io
import re

import numpy as np
import pytest

from stablemofusion.cli.main import main
from stablemofusion.core.errors import SMFError
from stablemofusion.motion.files import load_motion

WALK = np.cumsum(np.full((40, 22, 3), 0.01), axis=1)  # 40 frames of a 22-joint body with bones of 1.7 cm


def _npy(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array)
    return buf.getvalue()


@pytest.mark.parametrize("data, words", [
    (_npy(WALK)[:-100], "truncated"),
    (_npy(WALK).replace(b"(40, 22, 3)", b"(100000000, 22, 3)"), "header says 52800000128 bytes"),  # 53 GB asked
    (_npy(WALK) + b"1234", "extra bytes"),
    (_npy(WALK.astype(complex)), "not real numbers"),
    (b"\x93NUMPY\x01\x00junk", "not a readable .npy array"),
    (_npy(np.zeros((2, 40, 22, 3, 1))), "neither joints"),
    (_npy(WALK * 1e30), "finite numbers of at most 1e+06"),
    (_npy(np.where(np.arange(40)[:, None, None] == 3, np.nan, WALK)), "NaN or inf"),
])
def test_a_malformed_npy_is_one_line_at_the_library_and_the_command_line(tmp_path, capsys, data, words):
    path = tmp_path / "m.npy"
    path.write_bytes(data)
    with pytest.raises(SMFError, match=re.escape(words)):
        load_motion(path)
    assert main(["convert", str(path), str(tmp_path / "out.bvh")]) == 2
    err = capsys.readouterr().err
    assert words in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out.bvh").exists()
    if "neither joints" not in words and "NaN" not in words:  # a path .npy is (T, 2): its shape is not a body's
        assert main(["edit", "a person walks", "--motion", "example:wave-both-hands", "--mode", "trajectory", "--path", str(path),
                     "--engine", "onnx", "--out", str(tmp_path / "edited")]) == 2
        err = capsys.readouterr().err
        assert words in err and len(err.strip().splitlines()) == 1, err


def test_a_good_npy_still_reads(tmp_path):
    path = tmp_path / "m.npy"
    path.write_bytes(_npy(np.asfortranarray(WALK)))
    assert np.allclose(load_motion(path).joints, WALK)
