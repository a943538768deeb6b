"""Every command in the README's and docs' code blocks still reads as its program reads it, and
every link in them leads somewhere."""

import re
from pathlib import Path

from check_doc_commands import ROOT, arguments, check, commands, main


def test_every_documented_command_checks(capsys):
    assert main([]) == 0, capsys.readouterr().out
    readme = commands(ROOT / "README.md")
    assert len(readme) >= 10 and any("+profile=quickstart" in c for c in readme)


def test_the_checker_catches_what_a_user_would_hit():
    for command, problem in (
        ("python roto_trl/train.py +exp=find_ppo agent.lrr=1", "ConfigCompositionException"),
        ("python roto_trl/train.py +exp=find_ppo +agent.lrr=1", "agent.lrr is not a config key"),
        ("python roto_trl/train.py resume=runs/x agent.lr=1", "resume= takes only"),
        ("python roto_trl/evaluate.py run=x weights=trained", "unknown keys ['weights']"),
        ("python roto_trl/analyse.py curves 'runs/*' --metrik x", "do not parse"),
        ("python benchmarks/train_throughput.py --fused", "--help does not list: ['--fused']"),
    ):
        assert problem in (check(*arguments(command)) or ""), command


LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")  # [text](target) and ![alt](target)
FENCE = re.compile(r"^```.*?^```", re.S | re.M)


def headings(markdown: str) -> set[str]:
    """The anchors GitHub makes of a document's headings: lower case, punctuation but hyphens
    dropped, spaces as hyphens, a repeated one suffixed -1, -2, ..."""
    seen: dict[str, int] = {}
    for title in re.findall(r"^#+\s+(.*)$", FENCE.sub("", markdown), re.M):
        slug = re.sub(r"[^\w\- ]", "", title.strip().lower()).replace(" ", "-")
        seen[slug] = seen.get(slug, -1) + 1
    return {slug if n == 0 else f"{slug}-{n}" for slug, count in seen.items() for n in range(count + 1)}


def broken_links(path: Path) -> list[str]:
    """The relative links and images of the Markdown file ``path`` whose file or heading is missing."""
    broken = []
    for target in LINK.findall(FENCE.sub("", path.read_text())):
        if re.match(r"[a-z]+:", target):  # https:, mailto:
            continue
        file, _, anchor = target.partition("#")
        dest = (path.parent / file).resolve() if file else path
        markdown = dest.suffix == ".md"
        if not dest.exists() or (anchor and markdown and anchor not in headings(dest.read_text())):
            broken.append(target)
    return broken


def test_every_link_in_the_readme_and_docs_leads_to_a_file_and_heading(tmp_path):
    documents = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    assert {str(d.relative_to(ROOT)): broken_links(d) for d in documents if broken_links(d)} == {}
    page = tmp_path / "page.md"
    page.write_text("# A title\n## A title\n[ok](#a-title-1) [gone](x.md#a) [no heading](#b) ![x](page.md)\n")
    assert broken_links(page) == ["x.md#a", "#b"]
