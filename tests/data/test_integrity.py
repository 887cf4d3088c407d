"""Pure parts of the integrity tools: the fix command ``uavbench verify`` prints, OS error lines,
the render journal and the cache identity (the fault scenarios: ``tests/faults``)."""

from __future__ import annotations

import errno
import os
import time

from benchmark.data.format import os_error_message
from benchmark.data.integrity import cache_file, identity
from benchmark.data.journal import JOURNAL, append_journal, read_journal, trusted
from benchmark.data.profiles import DATA_PROFILES, get_data_profile
from benchmark.data.verify import simulate_command


def manifest_of(profile, seed):
    return {"profile": profile.to_dict(), "seed": seed}


class TestSimulateCommand:
    def test_default_profile(self, tmp_path):
        cmd = simulate_command(tmp_path, manifest_of(DATA_PROFILES["quick"], 0))
        assert cmd == f"`uavbench simulate --profile quick --out {tmp_path}`"

    def test_size_and_seed(self, tmp_path):
        cmd = simulate_command(tmp_path, manifest_of(get_data_profile("smoke", 30), 3))
        assert cmd == f"`uavbench simulate --profile smoke --size 30 --seed 3 --out {tmp_path}`"

    def test_profile_the_command_does_not_offer(self, tmp_path):
        cmd = simulate_command(tmp_path, manifest_of(DATA_PROFILES["quick"].standard_only(), 2))
        assert "profile quick-standard, seed 2" in cmd and "`" not in cmd


class TestOsErrorMessage:
    def test_disk_full_names_path_and_free_space(self, tmp_path):
        msg = os_error_message(OSError(errno.ENOSPC, "No space", str(tmp_path / "a" / "b.npy")))
        assert msg.startswith(f"{tmp_path / 'a' / 'b.npy'}: no space left on the device, ")
        assert "GB free" in msg and "rerun the same command" in msg

    def test_other_errors_are_not_rephrased(self):
        assert os_error_message(OSError(errno.EIO, "I/O error", "/x")) is None
        assert os_error_message(FileNotFoundError(errno.ENOENT, "gone", "/x")) is None


class TestJournal:
    def test_round_trip_last_line_wins_and_cut_line_ignored(self, tmp_path):
        append_journal(tmp_path, "uav/shard_00000.npy", "a" * 64, 10)
        append_journal(tmp_path, "uav/shard_00000.npy", "b" * 64, 11, "manifest")
        with open(tmp_path / JOURNAL, "a") as fh:
            fh.write('{"file": "uav/shard_00001.npy", "sha2')  # killed mid-line
        assert read_journal(tmp_path) == {
            "uav/shard_00000.npy": {"sha256": "b" * 64, "bytes": 11, "source": "manifest"}
        }

    def test_trusted_only_while_bytes_match(self, tmp_path):
        import hashlib

        (tmp_path / "f.npy").write_bytes(b"rendered")
        append_journal(tmp_path, "f.npy", hashlib.sha256(b"rendered").hexdigest(), 8)
        assert trusted(tmp_path, "f.npy", read_journal(tmp_path)) is not None
        (tmp_path / "f.npy").write_bytes(b"rendereD")  # same size, other bytes
        assert trusted(tmp_path, "f.npy", read_journal(tmp_path)) is None
        assert trusted(tmp_path, "g.npy", read_journal(tmp_path)) is None


class TestCacheIdentity:
    def test_cache_outside_the_dataset_one_file_per_path(self, tmp_path, monkeypatch):
        monkeypatch.setenv("UAVBENCH_VERIFY_CACHE", str(tmp_path / "c"))
        a, b = cache_file(tmp_path / "a"), cache_file(tmp_path / "b")
        assert a.parent == b.parent == tmp_path / "c" and a != b

    def test_identity_changes_with_a_same_size_rewrite(self, tmp_path):
        path = tmp_path / "f"
        path.write_bytes(b"12345678")
        before = identity(path, "x")
        st = path.stat()
        time.sleep(0.05)  # past the kernel's coarse timestamp tick (closer: RACY_NS's business)
        path.write_bytes(b"87654321")
        os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))  # size and mtime as before
        after = identity(path, "x")
        assert after[:2] == before[:2] and after != before  # the ctime tells
        assert identity(path, "y") != after  # another expected digest: another verdict
