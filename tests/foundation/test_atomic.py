"""The atomic writer's guard against outputs that would overwrite an input."""
import pytest

from pcdet_memslidar.errors import OutputError
from pcdet_memslidar.utils.atomic import refuse_overlap


def test_refuse_overlap_names_output_input_and_fix(tmp_path):
    source = tmp_path / "data" / "rec.bfpc"
    assert refuse_overlap(tmp_path / "out", [source]) == (tmp_path / "out").resolve()
    assert refuse_overlap(source.parent / "sub", [source.parent]) == (source.parent / "sub").resolve()  # inside: ok
    with pytest.raises(OutputError, match=r"--out .*data contains the input .*rec\.bfpc; choose --out outside"):
        refuse_overlap(tmp_path / "data", [source], "--out")
    with pytest.raises(OutputError, match=r"OUT .*data is the input .*data; choose OUT outside"):
        refuse_overlap(tmp_path / "data" / ".", [tmp_path / "data"], "OUT")
