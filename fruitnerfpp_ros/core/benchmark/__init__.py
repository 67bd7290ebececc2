"""Accuracy benchmark (issue #11): synthetic scene suites with ground truth, counted by the pipeline and by the
tracking peer, scored alike, reported as ``accuracy.json`` / ``accuracy.md`` (``fruitnerfpp bench accuracy``).

- ``suites.py``: the suites as data (:class:`SuiteScene` per scene; ``quick``, ``cpu``, ``gpu``).
- ``scene_run.py``: one scene in its own process (generate, masks, count, peer, score, picture).
- ``runner.py``: the scenes, ``jobs`` at once, then the reports.
- ``result.py``: :class:`SceneResult` / :class:`SuiteResult` records (JSON round trip).
- ``report.py``: Markdown tables and the section appended to the running log.

Importing this package does not import torch.
"""

from fruitnerfpp_ros.core.benchmark.report import append_log_section, git_commit, render_log_section, render_markdown
from fruitnerfpp_ros.core.benchmark.result import CounterScore, SceneResult, SuiteResult
from fruitnerfpp_ros.core.benchmark.runner import ACCURACY_JSON, ACCURACY_MD, MASK_SOURCES, SuiteOptions, run_suite
from fruitnerfpp_ros.core.benchmark.scene_run import BagReplayOutcome, BagReplayRequest, SceneJob, run_scene
from fruitnerfpp_ros.core.benchmark.suites import SUITE_NAMES, SUITES, BagOptions, Suite, SuiteScene, suite_scenes

__all__ = ['SuiteScene', 'BagOptions', 'Suite', 'SUITES', 'SUITE_NAMES', 'suite_scenes', 'SuiteOptions', 'run_suite',
           'SceneJob', 'run_scene', 'BagReplayRequest', 'BagReplayOutcome', 'CounterScore', 'SceneResult',
           'SuiteResult', 'render_markdown', 'render_log_section', 'append_log_section', 'git_commit',
           'ACCURACY_JSON', 'ACCURACY_MD', 'MASK_SOURCES']
