"""Markdown of an accuracy suite run: ``accuracy.md`` and the section appended to the running log
(``docs/results/accuracy_suite.md``, by ``fruitnerfpp bench accuracy ... --log FILE``).

Tables: accuracy per scene (ours and the tracking peer), time and memory per scene, the scenes and the axes each
covers; then mean and worst F1 of both counters and the suite's wall time. A failed scene keeps its row, with its
error in place of the count, and its figures where it measured them.
"""

from __future__ import annotations

import math
import subprocess
from pathlib import Path
from typing import Iterable

from fruitnerfpp_ros.core.atomic_io import atomic_write_text
from fruitnerfpp_ros.core.benchmark.result import TIME_KEYS, SceneResult, SuiteResult
from fruitnerfpp_ros.errors import ConfigError

__all__ = ['accuracy_table', 'cost_table', 'scenes_table', 'summary_lines', 'render_markdown', 'render_log_section',
           'append_log_section', 'git_commit', 'LOG_TITLE']

#: First line of a new running log.
LOG_TITLE = '# Accuracy suite: running log'
_DASH = '–'


def _num(value: float | None, digits: int = 3) -> str:
    if value is None or not math.isfinite(value):
        return _DASH
    return f'{value:.{digits}f}'


def _cell(text: str) -> str:
    """Text safe inside a table cell: one line, no pipes, no code spans."""
    return ' '.join(str(text).replace('|', '/').replace('`', "'").split())


def _table(header: Iterable[str], rows: Iterable[Iterable[str]], align: str) -> str:
    header = list(header)
    lines = ['| ' + ' | '.join(header) + ' |', '|' + '|'.join(':---' if a == 'l' else '---:' for a in align) + '|']
    lines += ['| ' + ' | '.join(_cell(c) for c in row) + ' |' for row in rows]
    return '\n'.join(lines)


def _error_excerpt(scene: SceneResult, limit: int = 90) -> str:
    text = _cell(scene.error)
    return 'failed: ' + (text if len(text) <= limit else text[:limit - 1] + '…')


def accuracy_table(suite: SuiteResult, *, pictures: bool = False) -> str:
    """Per scene: count / GT, precision, recall, F1 (ours), the peer's count and F1, F1 difference, held-out PSNR /
    semantic IoU / instance accuracy, scene box, export voxel, fruit diameter measured / GT (and, with
    ``pictures``, a link to the count picture, relative to the suite's output directory)."""
    header = ['scene', 'count / GT', 'P', 'R', 'F1', 'peer count', 'peer F1', 'ΔF1', 'PSNR dB', 'sem IoU',
              'inst acc', 'box m', 'voxel mm', 'diam mm (GT)']
    if pictures:
        header.append('picture')
    rows = []
    for s in suite.scenes:
        name = s.name + (' (bag)' if s.via_bag else '')
        ours = s.ours
        count = f'{ours.count} / {s.gt_count}' if ours is not None else _error_excerpt(s)
        if ours is not None and s.error:
            count += ' (' + _error_excerpt(s) + ')'
        box = _DASH if s.box_size_m is None else ' x '.join(f'{v:.2f}' for v in s.box_size_m)
        diameter = f'{_num(s.diameter_m * 1e3, 1)} ({_num(s.gt_diameter_m * 1e3, 1)})'
        row = [name, count,
               _num(ours.precision if ours else None), _num(ours.recall if ours else None),
               _num(ours.f1 if ours else None),
               f'{s.peer.count}' if s.peer else (_error_excerpt(s, 40) if ours is not None else _DASH),
               _num(s.peer.f1 if s.peer else None), _signed(s.f1_delta), _num(s.psnr_db, 2),
               _num(s.semantic_iou), _num(s.instance_acc), box, _num(s.voxel_mm, 1), diameter]
        if pictures:
            row.append(f'[count.png]({s.picture})' if s.picture else _DASH)
        rows.append(row)
    return _table(header, rows, 'l' + 'r' * (len(header) - 1))


def _signed(value: float) -> str:
    return _DASH if not math.isfinite(value) else f'{value:+.3f}'


def cost_table(suite: SuiteResult) -> str:
    """Per scene: wall seconds of each step (:data:`TIME_KEYS`: synth, fallback masks, bag keyframes, training's
    preparation, the three training stages, held-out evaluation, checkpoint writes, export, count, ours from the
    data to the count, tracking, whole scene) and peak memory (process RSS; CUDA peak allocation on the GPU)."""
    header = ['scene', 'synth s', 'masks s', 'keyframes s', 'prepare s', 'geometry s', 'semantic s', 'instance s',
              'held-out eval s', 'checkpoints s', 'export s', 'count s', 'ours s', 'tracking s', 'total s',
              'peak RSS MiB', 'CUDA MiB']
    rows = [[s.name, *(_num(s.times_s.get(k), 1) for k in TIME_KEYS), _num(s.peak_rss_mb, 0),
             _num(s.cuda_max_allocated_mb, 0)] for s in suite.scenes]
    return _table(header, rows, 'l' + 'r' * (len(header) - 1))


def scenes_table(suite: SuiteResult) -> str:
    """The scenes: name, transport (dataset or bag replay) and the axes each covers."""
    rows = [[s.name, 'rosbag2 + replay' if s.via_bag else 'dataset', s.covers] for s in suite.scenes]
    return _table(['scene', 'through', 'covers'], rows, 'lll')


def summary_lines(suite: SuiteResult) -> list[str]:
    """Mean and worst F1 of ours and the peer, failures and total time, as Markdown list items."""
    lines = []
    for who, label in (('ours', 'FruitNeRF++ (ours)'), ('peer', 'tracking peer')):
        worst, where = suite.worst(who)
        scored = len(suite.f1s(who))
        lines.append(f'- {label}: mean F1 **{_num(suite.mean_f1(who))}**, worst {_num(worst)}'
                     + (f' ({where})' if where else '') + f' over {scored} of {len(suite.scenes)} scenes')
    failed = suite.failed
    lines.append(f'- failed scenes: {len(failed)}' + (': ' + ', '.join(s.name for s in failed) if failed else ''))
    if suite.pending:
        lines.append(f'- **unfinished run**: {len(suite.pending)} scene(s) still to come ({", ".join(suite.pending)}); '
                     f'{_num(suite.total_s, 0)} s so far, {suite.jobs} scene(s) at once')
        return lines
    lines.append(f'- total time: {_num(suite.total_s, 0)} s ({_num(suite.total_s / 60, 1)} min), '
                 f'{suite.jobs} scene(s) at once')
    timed = [(s.times_s['ours'], s.times_s.get('total', math.nan), s.name) for s in suite.scenes
             if math.isfinite(s.times_s.get('ours', math.nan))]
    if timed:
        ours, total, name = max(timed)
        lines.append(f'- slowest count, data to count: {_num(ours, 0)} s ({name}; {_num(total, 0)} s with the '
                     'scene generation and the peer)')
    return lines


def _settings_line(suite: SuiteResult) -> str:
    config = f', config {Path(suite.config_file).name}' if suite.config_file else ''
    return (f'suite **{suite.suite}**, preset {suite.preset}, masks {suite.masks}, device {suite.device}, '
            f'--jobs {suite.jobs}{config}')


def _errors(suite: SuiteResult) -> list[str]:
    if not suite.failed:
        return []
    return ['', '### Errors', ''] + [f'- {s.name}: {_cell(s.error)}' for s in suite.failed]


def render_markdown(suite: SuiteResult) -> str:
    """``accuracy.md`` of a run (pictures linked relative to the suite's output directory)."""
    lines = [f'# Accuracy suite {suite.suite}', '',
             f'{suite.started_utc}, commit {suite.git_commit or "unknown"}: {_settings_line(suite)}', '']
    if suite.command:
        lines += [f'`{suite.command}`', '']
    lines += ['## Counts against ground truth', '',
              'Hungarian matching within one ground-truth diameter; recall over the fruits a training view sees. '
              'Peer: tracking-by-detection of the same instance masks over every frame (`fruitnerfpp track`), '
              'scored the same way. '
              'Held-out figures: after the last training stage.', '',
              accuracy_table(suite, pictures=True), '', *summary_lines(suite), '',
              '## Time and memory', '', cost_table(suite), '', '## Scenes', '', scenes_table(suite),
              *_errors(suite)]
    return '\n'.join(lines) + '\n'


def render_log_section(suite: SuiteResult) -> str:
    """One run as a section of the running log: date, commit, command, accuracy and cost tables, means.

    The section names no file of the run's output directory (the log lives in the repository; the outputs do
    not), so it links no picture.
    """
    date = suite.started_utc[:10] or 'undated'
    lines = [f'## {date} {suite.suite} suite, commit {suite.git_commit or "unknown"}', '',
             f'{suite.started_utc}: {_settings_line(suite)}', '']
    if suite.command:
        lines += [f'`{suite.command}`', '']
    lines += [accuracy_table(suite), '', *summary_lines(suite), '', cost_table(suite), *_errors(suite)]
    return '\n'.join(lines) + '\n'


def append_log_section(path: str | Path, suite: SuiteResult) -> Path:
    """Append :func:`render_log_section` to the running log at ``path`` (created with a title when missing).

    Raises:
        ConfigError: the log cannot be read or written.
    """
    path = Path(path)
    try:
        before = path.read_text() if path.exists() else LOG_TITLE + '\n'
    except OSError as err:
        raise ConfigError(f'cannot read the log {path}: {err}') from err
    text = before.rstrip('\n') + '\n\n' + render_log_section(suite)
    try:
        return atomic_write_text(path, text)
    except OSError as err:
        raise ConfigError(f'cannot write the log {path}: {err}') from err


def git_commit(where: str | Path | None = None) -> str:
    """``git rev-parse --short HEAD`` of the repository holding ``where`` (default: this package), with
    ``+dirty`` when tracked files differ from it; ``''`` when git or the repository is not available."""
    cwd = Path(where) if where is not None else Path(__file__).resolve().parent
    try:
        commit = subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=cwd, capture_output=True, text=True,
                                timeout=10, check=True).stdout.strip()
        dirty = subprocess.run(['git', 'diff', '--quiet', 'HEAD', '--'], cwd=cwd, capture_output=True,
                               timeout=30).returncode == 1
    except (OSError, subprocess.SubprocessError):
        return ''
    return commit + ('+dirty' if dirty else '')
