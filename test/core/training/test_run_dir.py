"""Where a run finds the dataset it was trained on: recorded absolute and from the run, found after a move."""

from __future__ import annotations

from pathlib import Path

from fruitnerfpp_ros.core.training import RunDir


def _dataset(path: Path) -> Path:
    path.mkdir(parents=True)
    (path / 'transforms.json').write_text('{}')
    return path


def test_a_checkpoint_names_its_dataset_absolute_and_from_the_run(tmp_path: Path, monkeypatch) -> None:
    _dataset(tmp_path / 'scene' / 'data')
    monkeypatch.chdir(tmp_path)
    record = RunDir('scene/run').dataset_record('scene/data')      # relative paths, as a user types them
    assert record == {'dataset_dir': str(tmp_path.resolve() / 'scene' / 'data'), 'dataset_from_run': '../data'}


def test_a_run_moved_with_its_dataset_finds_it(tmp_path: Path) -> None:
    record = RunDir(tmp_path / 'old' / 'run').dataset_record(tmp_path / 'old' / 'data')   # where it trained
    moved = _dataset(tmp_path / 'new' / 'data')
    assert RunDir(tmp_path / 'new' / 'run').find_dataset(record).resolve() == moved.resolve()


def test_the_recorded_path_comes_first(tmp_path: Path) -> None:
    recorded = _dataset(tmp_path / 'kept' / 'data')
    _dataset(tmp_path / 'new' / 'data')
    record = {'dataset_dir': str(recorded), 'dataset_from_run': '../data'}
    assert RunDir(tmp_path / 'new' / 'run').find_dataset(record) == recorded


def test_an_older_checkpoints_relative_path_is_found_from_above_the_run(tmp_path: Path, monkeypatch) -> None:
    data = _dataset(tmp_path / 'site' / 'A' / 'data')
    (tmp_path / 'elsewhere').mkdir()
    monkeypatch.chdir(tmp_path / 'elsewhere')
    # written by `fruitnerfpp run A/data --out A/run` in site/: the path relative to that working directory
    found = RunDir(tmp_path / 'site' / 'A' / 'run').find_dataset({'dataset_dir': 'A/data'})
    assert found.resolve() == data.resolve()


def test_no_dataset_anywhere_gives_the_recorded_path(tmp_path: Path) -> None:
    record = {'dataset_dir': str(tmp_path / 'gone' / 'data'), 'dataset_from_run': '../data'}
    assert RunDir(tmp_path / 'run').find_dataset(record) == tmp_path / 'gone' / 'data'
