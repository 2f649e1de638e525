"""The documentation's links: every relative link of a tracked Markdown file reaches a file
of the repository, and every ``#anchor`` a heading of its page (GitHub's heading slugs), so
that moving a section cannot leave a reader at a dead link; and the bench parts the docs list
are the ones ``mlkm bench --only`` takes."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
LINK = re.compile(r'\]\(([^)\s]+)\)')
FENCE = re.compile(r'^```.*?^```', re.S | re.M)
CODE = re.compile(r'`[^`\n]*`')


def _markdown_files() -> list[Path]:
    out = subprocess.run(
        ['git', 'ls-files', '*.md'], cwd=ROOT, capture_output=True, text=True, check=True
    ).stdout
    return [ROOT / name for name in out.split()]


def slugs(text: str) -> set[str]:
    """GitHub's anchors of the headings in ``text``: lower case, punctuation other than '-'
    and '_' dropped, spaces as '-', a repeated heading numbered '-1', '-2', ..."""
    seen: dict[str, int] = {}
    out = set()
    for line in FENCE.sub('', text).splitlines():
        m = re.match(r'#{1,6}\s+(.*)$', line)
        if m:
            slug = re.sub(r'[^\w\- ]', '', m.group(1).strip().lower()).replace(' ', '-')
            n = seen.get(slug, 0)
            seen[slug] = n + 1
            out.add(slug if n == 0 else f'{slug}-{n}')
    return out


def broken_links(page: Path) -> list[str]:
    """The relative links of ``page`` that reach no file or no heading, with the reason."""
    bad = []
    text = CODE.sub('', FENCE.sub('', page.read_text()))
    for target in LINK.findall(text):
        if re.match(r'[a-z][a-z0-9+.-]*:', target):  # https:, mailto:, ...
            continue
        path, _, anchor = target.partition('#')
        dest = (page.parent / path).resolve() if path else page
        if not dest.exists():
            bad.append(f'{target}: no such file')
        elif anchor and dest.suffix == '.md' and anchor not in slugs(dest.read_text()):
            bad.append(f'{target}: no heading #{anchor}')
    return bad


def test_slugs_follow_githubs_rules():
    text = '# How accurate it is, on real traffic and on ours\n## `mlkm paper` and `mlkm bench`\n'
    text += '```\n# not a heading\n```\n## Tests\n## Tests\n'
    assert slugs(text) == {
        'how-accurate-it-is-on-real-traffic-and-on-ours',
        'mlkm-paper-and-mlkm-bench',
        'tests',
        'tests-1',
    }


def test_a_dead_link_and_a_dead_anchor_are_found(tmp_path):
    (tmp_path / 'other.md').write_text('# Present\n')
    page = tmp_path / 'page.md'
    page.write_text(
        '[ok](other.md#present) [gone](missing.md) [no](other.md#absent) [web](https://x.org)\n'
        '`[in code](nowhere.md)` [self](#top)\n# Top\n'
    )
    assert broken_links(page) == [
        'missing.md: no such file',
        'other.md#absent: no heading #absent',
    ]


@pytest.mark.parametrize('page', _markdown_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_reaches_its_file_and_heading(page):
    assert broken_links(page) == []


def test_the_docs_list_every_bench_part():
    from mlkm_experiments.bench.main import PARTS

    text = (ROOT / 'docs' / 'cli.md').read_text()
    listed = re.search(r'`--only ([a-z|]+)`', text)
    assert listed and tuple(listed.group(1).split('|')) == PARTS
