"""``git_commit``: the commit a result ran, dirty when tracked code changed, and not dirty when only
the run's own output directory changed. Checked against ``git`` itself on a throwaway
repository."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from benchmark.tracking import git_commit

pytestmark = pytest.mark.skipif(shutil.which("git") is None, reason="no git executable")


def git(repo: Path, *args: str) -> str:
    env = {"GIT_AUTHOR_NAME": "t", "GIT_AUTHOR_EMAIL": "t@t", "GIT_COMMITTER_NAME": "t",
           "GIT_COMMITTER_EMAIL": "t@t", "HOME": str(repo), "PATH": "/usr/bin:/bin"}  # fmt: skip
    done = subprocess.run(["git", *args], cwd=repo, capture_output=True, text=True, env=env)
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


@pytest.fixture
def repo(tmp_path: Path) -> Path:
    """A repository with code in ``pkg/`` and a committed report in ``reports/quick``."""
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "code.py").write_text("x = 1\n")
    (tmp_path / "reports" / "quick").mkdir(parents=True)
    (tmp_path / "reports" / "quick" / "table1.md").write_text("old\n")
    git(tmp_path, "init", "-q")
    git(tmp_path, "add", "-A")
    git(tmp_path, "commit", "-q", "-m", "first")
    return tmp_path


class TestGitCommit:
    def test_clean_tree_is_head(self, repo: Path) -> None:
        assert git_commit(repo / "pkg") == git(repo, "rev-parse", "HEAD")

    def test_changed_code_is_dirty(self, repo: Path) -> None:
        (repo / "pkg" / "code.py").write_text("x = 2\n")
        head = git(repo, "rev-parse", "HEAD")
        assert git_commit(repo / "pkg") == f"{head}-dirty"
        # ignoring the report directory does not hide a change of code
        assert git_commit(repo / "pkg", ignore=[repo / "reports" / "quick"]) == f"{head}-dirty"

    def test_the_runs_own_report_does_not_make_it_dirty(self, repo: Path, monkeypatch) -> None:
        (repo / "reports" / "quick" / "table1.md").write_text("new\n")
        head = git(repo, "rev-parse", "HEAD")
        assert git_commit(repo / "pkg") == f"{head}-dirty"  # without ignore: git's own view
        assert git_commit(repo / "pkg", ignore=[repo / "reports" / "quick"]) == head
        # given relative to the current directory, as the runner's --out is
        monkeypatch.chdir(repo)
        assert git_commit(repo / "pkg", ignore=[Path("reports/quick")]) == head

    def test_a_directory_outside_the_tree_is_skipped(self, repo: Path, tmp_path_factory) -> None:
        elsewhere = tmp_path_factory.mktemp("elsewhere")
        (repo / "pkg" / "code.py").write_text("x = 3\n")
        head = git(repo, "rev-parse", "HEAD")
        assert git_commit(repo / "pkg", ignore=[elsewhere]) == f"{head}-dirty"

    def test_ignoring_the_whole_tree_ignores_nothing(self, repo: Path) -> None:
        (repo / "pkg" / "code.py").write_text("x = 4\n")
        head = git(repo, "rev-parse", "HEAD")
        assert git_commit(repo / "pkg", ignore=[repo]) == f"{head}-dirty"

    def test_outside_git_is_none(self, tmp_path_factory) -> None:
        assert git_commit(tmp_path_factory.mktemp("nogit")) is None
