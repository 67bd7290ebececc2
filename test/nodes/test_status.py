"""The node's typed status records: state per pipeline stage, the diagnostics built from a snapshot."""

from __future__ import annotations

from pathlib import Path

import pytest

from fruitnerfpp_ros.core.progress import Phase, PipelineStage
from fruitnerfpp_ros.nodes.status import AssemblerStatus, DiagnosticLevel, NodeState, NodeStatus, RunStatus


@pytest.mark.parametrize('phase, state', [
    (Phase.TRAIN_GEOMETRY, NodeState.TRAINING), (Phase.TRAIN_SEMANTIC, NodeState.TRAINING),
    (Phase.TRAIN_INSTANCE, NodeState.TRAINING), (Phase.EXPORT_COARSE, NodeState.EXPORTING),
    (Phase.EXPORT, NodeState.EXPORTING), (Phase.CLUSTER, NodeState.COUNTING)])
def test_each_pipeline_phase_has_its_node_state(phase: Phase, state: NodeState) -> None:
    assert NodeState.during(phase.stage) is state


def test_stages_outside_the_pipeline_report_training() -> None:
    assert NodeState.during(PipelineStage.SEGMENT) is NodeState.TRAINING
    assert NodeState.during(PipelineStage.SYNTH) is NodeState.TRAINING


def _status(run: RunStatus, silent: tuple[str, ...] = ()) -> NodeStatus:
    frames = AssemblerStatus(7, received={'image': 9}, errors={'image': 1, 'frame': 2},
                             rejected={'too_close': 5, 'blurry': 0}, sync_unmatched={'image': 3, 'mask': 1},
                             write_errors=1, time_jumps=2)
    return NodeStatus.from_parts(run, frames, dropped_queue=4, run_dir=Path('/tmp/run'),
                                 rates_hz={'/camera/image_raw': 10.04}, silent_topics=silent,
                                 dropped_per_topic={'/camera/image_raw': 4},
                                 received_per_topic={'/camera/image_raw': 9})


def test_diagnostics_values_keep_the_published_keys_and_formats() -> None:
    status = _status(RunStatus(NodeState.EXPORTING, Phase.EXPORT, 0.4567))
    assert status.values() == {
        'state': 'exporting', 'phase': 'export', 'progress': '0.457', 'keyframes': '7', 'fruit_count': '',
        'run_dir': '/tmp/run', 'dropped_queue': '4', 'frame_errors': '3', 'sync_unmatched': '4',
        'rate_hz//camera/image_raw': '10.0', 'skipped/frame': '2', 'skipped/image': '1', 'rejected/too_close': '5',
        'dropped_queue//camera/image_raw': '4', 'write_errors': '1', 'time_jumps': '2',
        'received//camera/image_raw': '9'}
    assert status.message() == 'exporting export 46%' and status.level is DiagnosticLevel.OK
    done = _status(RunStatus(NodeState.DONE, None, 1.0, last_count=12)).values()
    assert (done['state'], done['phase'], done['fruit_count']) == ('done', '', '12')


def test_silent_inputs_warn_and_a_failed_run_is_an_error() -> None:
    silent = _status(RunStatus(), silent=('/camera/image_raw', '/camera/pose'))
    assert silent.level is DiagnosticLevel.WARN
    assert silent.message() == 'collecting; silent inputs: /camera/image_raw, /camera/pose'
    failed = _status(RunStatus(NodeState.ERROR, last_error='DatasetError: no keyframes'))
    assert failed.level is DiagnosticLevel.ERROR and failed.message() == 'error; DatasetError: no keyframes'


def test_a_failed_keyframe_write_is_an_error_in_diagnostics() -> None:
    frames = AssemblerStatus(3, write_errors=1)
    status = NodeStatus.from_parts(RunStatus(), frames, dropped_queue=0, run_dir=Path('/r'), rates_hz={},
                                   silent_topics=(), write_error='keyframe 3 not stored (No space left on device)')
    assert status.level is DiagnosticLevel.ERROR
    assert status.message() == 'collecting; keyframe 3 not stored (No space left on device)'


def test_assembler_status_totals() -> None:
    frames = AssemblerStatus(0, errors={'image': 2, 'waiting': 1}, sync_unmatched={'pose': 5})
    assert (frames.total_errors, frames.total_sync_unmatched) == (3, 5)
    assert AssemblerStatus(0).total_errors == 0
