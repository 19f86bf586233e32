"""The internal-error line names the place in pcdet by the package's own location, not by a path pattern."""
from pathlib import Path

import pcdet
from pcdet.errors import internal_error


def _raise_from(filename: str):
    """An IndexError raised by code whose file is ``filename`` (compiled under that name, never written)."""
    space: dict = {}
    exec(compile("def boom():\n    raise IndexError('made to fail')\n", filename, "exec"), space)
    try:
        space["boom"]()
    except IndexError as e:
        return e
    raise AssertionError("boom did not raise")


def test_a_file_under_a_folder_named_pcdet_is_not_taken_for_the_package(tmp_path):
    """A checkout in a folder named ``pcdet`` holds ``pcdet/tests/...``: such a file is named by its own path."""
    fake = str(tmp_path / "pcdet" / "tests" / "test_x.py")
    line = internal_error(_raise_from(fake))
    assert line == f"internal error (please report it): IndexError at {fake}:2 in boom: made to fail"


def test_a_place_inside_the_package_is_named_relative_to_it():
    real = Path(pcdet.__file__).resolve().parent / "detector.py"
    line = internal_error(_raise_from(str(real)))
    assert line == "internal error (please report it): IndexError at pcdet/detector.py:2 in boom: made to fail"
