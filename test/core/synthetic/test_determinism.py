"""Same seed -> byte-identical outputs (dataset files and mcap bag); another seed -> another tree."""

from __future__ import annotations

from pathlib import Path

from fruitnerfpp_ros.core.synthetic import SynthConfig, generate_orchard


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob('*')) if p.is_file()}


def test_same_seed_gives_byte_identical_outputs(tmp_path: Path) -> None:
    config = SynthConfig(fruit='pear', count=10, views=4, resolution=(48, 40), trajectory='row', seed=7)
    for run in ('a', 'b'):
        generate_orchard(config, tmp_path / run / 'ds', bag=tmp_path / run / 'bag',
                         preview=tmp_path / run / 'preview.png')
    a, b = _files(tmp_path / 'a'), _files(tmp_path / 'b')
    assert sorted(a) == sorted(b) and len(a) == 4 * 3 + 6
    assert any(name.endswith('.mcap') for name in a)
    different = [name for name in a if a[name] != b[name]]
    assert not different

    generate_orchard(SynthConfig(fruit='pear', count=10, views=4, resolution=(48, 40), trajectory='row', seed=8),
                     tmp_path / 'c')
    assert (tmp_path / 'c' / 'gt_fruits.json').read_bytes() != a['ds/gt_fruits.json']
