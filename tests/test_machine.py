"""``benchmark.machine``: the CPU facts a report records, parsed from ``/proc/cpuinfo`` text."""

from __future__ import annotations

import benchmark.machine as machine
from benchmark.machine import cpu_signature

TWO_PROCESSORS = """processor\t: 0
vendor_id\t: GenuineIntel
cpu family\t: 6
model\t\t: 143
model name\t: Intel(R) Xeon(R) Platinum 8480C
stepping\t: 8
microcode\t: 0x2b000590
cache size\t: 107520 KB
flags\t\t: fpu avx512f amx_tile

processor\t: 1
vendor_id\t: GenuineIntel
cpu family\t: 6
model\t\t: 106
stepping\t: 6
microcode\t: 0xd0003a5
cache size\t: 55296 KB
"""


class TestCpuSignature:
    def test_reads_the_first_processor_only(self):
        assert cpu_signature(TWO_PROCESSORS) == (
            "cpu family 6, model 143, stepping 8, microcode 0x2b000590, cache size 107520 KB"
        )

    def test_model_name_is_not_the_model_number(self):
        assert "Platinum" not in cpu_signature(TWO_PROCESSORS)

    def test_missing_fields_are_left_out(self):
        assert cpu_signature("processor\t: 0\ncpu family\t: 6\nmodel\t\t: 1\n") == (
            "cpu family 6, model 1"
        )

    def test_no_fields_is_unknown(self):
        assert cpu_signature("") == "unknown"
        assert cpu_signature("processor : 0\nflags : sse2\n") == "unknown"

    def test_this_machine_gives_a_string(self):
        assert isinstance(cpu_signature(), str) and cpu_signature()


class TestReadCpuinfo:
    def test_unreadable_file_gives_none_and_the_fallbacks(self, monkeypatch):
        class Unreadable:
            def __init__(self, *_):
                pass

            def read_text(self):
                raise PermissionError("/proc/cpuinfo")

        monkeypatch.setattr(machine, "Path", Unreadable)
        assert machine.read_cpuinfo() is None
        assert machine.cpu_signature() == "unknown"
        assert machine.cpu_model()  # platform's answer or "unknown CPU", never an exception
