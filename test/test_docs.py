"""README.md, docs/ and bench/ Markdown point only at files inside the repository (a user's clone has nothing
beside it)."""

from __future__ import annotations

import glob
import itertools
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / 'README.md', *sorted((ROOT / 'docs').rglob('*.md')), *sorted((ROOT / 'bench').rglob('*.md'))]
#: First path components that name a folder of the repository (``config/fruit_counter.yaml``) ...
REPO_DIRS = ('fruitnerfpp_ros', 'docs', 'config', 'bench', 'test', 'launch', 'resource', '.ci', 'rviz', 'foxglove')
#: ... or of the package, as the docs write them (``core/clustering``, ``nodes/params.py``).
PACKAGE_DIRS = ('core', 'nodes', 'cli')
#: Code spans with a slash that are names, not paths.
NOT_PATHS = {'fruitnerfpp_ros/fruit_report'}  # the report's JSON schema name
_LINK = re.compile(r'\]\(([^)\s]+)\)')
_CODE = re.compile(r'`([^`\n]+)`')
_FENCE = re.compile(r'```.*?```', re.S)


def _expand_braces(token: str) -> list[str]:
    """``config/train_{tiny,default}.yaml`` -> both names."""
    match = re.search(r'\{([^{}]*)\}', token)
    if not match:
        return [token]
    return list(itertools.chain.from_iterable(
        _expand_braces(token[:match.start()] + option + token[match.end():]) for option in match[1].split(',')))


def path_mentions(text: str) -> tuple[list[str], list[str]]:
    """(relative link targets, path-like words of code spans and code blocks) of a Markdown text."""
    links = [t.split('#')[0] for t in _LINK.findall(text) if not re.match(r'[a-z]+:|#', t)]
    words = []
    for span in _CODE.findall(_FENCE.sub('', text)) + [block.strip('`') for block in _FENCE.findall(text)]:
        for word in span.split():
            word = word.strip('\'"()[]<>,;:')
            if '/' in word and not word.startswith(('/', '~', '$', 'http')):
                words.extend(_expand_braces(word))
    return links, words


def _exists(path: Path) -> bool:
    """A file or folder, a glob matching something, a module (``a/b`` -> ``a/b.py``) or a module attribute
    (``a/b.Name`` -> ``a/b.py``)."""
    if '*' in path.name:
        return bool(glob.glob(str(path)))
    return path.exists() or path.with_name(path.name + '.py').exists() or \
        path.with_name(path.name.split('.')[0] + '.py').exists()


def _target(word: str, doc: Path) -> Path | None:
    """Where a code-span word points: paths are written from the repository root (``config/...``), the package
    (``core/...``) or the document (``../x``); None for words that are not repository paths (``RUN_DIR/...``,
    topic and message type names, ``install/`` trees)."""
    first = word.split('/')[0]
    if word in NOT_PATHS:
        return None
    if first in ('.', '..'):
        return (doc.parent / word).resolve()
    if first in REPO_DIRS:
        return ROOT / word
    if first in PACKAGE_DIRS:
        return ROOT / 'fruitnerfpp_ros' / word
    return None


def missing_paths(text: str, doc: Path) -> list[str]:
    """The links and path-like words of ``text`` (from ``doc``) that name nothing in the repository."""
    links, words = path_mentions(text)
    targets = [(link, (doc.parent / link).resolve()) for link in links if link]
    targets += [(word, target) for word in words if (target := _target(word, doc)) is not None]
    return [mention for mention, target in targets if not target.is_relative_to(ROOT) or not _exists(target)]


@pytest.mark.parametrize('doc', DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_docs_point_only_at_files_in_the_repository(doc: Path) -> None:
    missing = missing_paths(doc.read_text(), doc)
    assert not missing, f'{doc.relative_to(ROOT)} names {missing}, which the repository does not hold'


def test_the_check_catches_what_it_is_for() -> None:
    text = ('The paper (`../shared/paper`), see [the table](docs/nope.md) and [up](../outside.md); '
            '`config/fruit_counter.yaml`, `config/train_{tiny,nope}.yaml`, `core/data/keyframe_store.KeyframeStore`, '
            '`nodes/params.py`, `RUN_DIR/counts.json`, `/fruit_counter/fruit_count`, `sensor_msgs/Image`, '
            '[web](https://arxiv.org/abs/2505.19863), [here](#references).\n'
            '```bash\nfruitnerfpp replay bag --params config/missing.yaml --out run1\n```\n')
    assert missing_paths(text, ROOT / 'README.md') == ['docs/nope.md', '../outside.md', '../shared/paper',
                                                       'config/train_nope.yaml', 'config/missing.yaml']
    # links are relative to their document, code-span paths to the repository
    assert missing_paths('[table](results/tiny_preset.md) `docs/results/tiny_preset.md`', ROOT / 'docs' / 'x.md') == []
    assert missing_paths('[table](docs/results/tiny_preset.md)', ROOT / 'docs' / 'x.md') == [
        'docs/results/tiny_preset.md']
