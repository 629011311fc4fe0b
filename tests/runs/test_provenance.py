"""The source digest that keys resumable results: it follows the package's Python source and nothing else."""

from __future__ import annotations

from pathlib import Path

from handradar.provenance import package_digest, source_digest


def test_source_digest_follows_python_source_only(tmp_path: Path):
    (tmp_path / "sub").mkdir()
    (tmp_path / "a.py").write_text("x = 1\n")
    (tmp_path / "sub" / "b.py").write_text("y = 2\n")
    before = source_digest(tmp_path)
    (tmp_path / "README.md").write_text("docs change nothing")
    assert source_digest(tmp_path) == before
    (tmp_path / "sub" / "b.py").write_text("y = 3\n")
    assert source_digest(tmp_path) != before
    (tmp_path / "sub" / "b.py").write_text("y = 2\n")
    assert source_digest(tmp_path) == before
    (tmp_path / "sub" / "b.py").rename(tmp_path / "b.py")  # same content, another module: another digest
    assert source_digest(tmp_path) != before


def test_package_digest_is_the_installed_package_source():
    import handradar

    assert package_digest() == source_digest(Path(handradar.__file__).resolve().parent)
    assert len(package_digest()) == 16 and int(package_digest(), 16) >= 0
