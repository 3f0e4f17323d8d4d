"""The torch install line says what it does: `pip install torch==2.13.0` gets whatever build
the index serves (the CUDA one from PyPI on Linux x86-64), so every user page that gives the
line also says how to get the CPU-only wheel from PyTorch's own index, or links to the
install page's section that does. The CI line (the README's test command) stays as it is."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CPU_INDEX = "--index-url https://download.pytorch.org/whl/cpu"
SECTION = "install.md#which-torch-build"


def _user_pages() -> list[Path]:
    docs = [p for p in (ROOT / "docs").rglob("*.md") if "notes" not in p.relative_to(ROOT / "docs").parts]
    return [ROOT / "README.md", ROOT / "CONTRIBUTING.md", *docs]


def test_the_install_page_gives_the_cpu_only_command():
    text = (ROOT / "docs" / "install.md").read_text()
    assert "### Which torch build" in text
    assert f"pip install torch==2.13.0 {CPU_INDEX}" in text


def test_every_page_with_the_torch_line_says_how_to_get_the_cpu_wheel():
    pages = [p for p in _user_pages() if "pip install torch==2.13.0" in p.read_text()]
    assert len(pages) >= 5, pages
    lacking = [str(p.relative_to(ROOT)) for p in pages
               if CPU_INDEX not in p.read_text() and SECTION not in p.read_text()]
    assert not lacking, f"pages giving the torch line without the CPU-only way: {lacking}"


def test_no_page_calls_the_default_index_build_the_cpu_build():
    claim = re.compile(r"torch==2\.13\.0`?[^.]{0,40}(?:is|,) the CPU build", re.IGNORECASE)
    wrong = [str(p.relative_to(ROOT)) for p in _user_pages() if claim.search(p.read_text())]
    assert not wrong, wrong


def test_the_ci_line_is_unchanged():
    readme = (ROOT / "README.md").read_text()
    block = readme.split("<!-- test-command -->", 1)[1].split("```", 2)[1]
    assert block.strip() == 'bash\npip install torch==2.13.0 && pip install -e ".[test]" && python -m pytest'
