"""Keeping freed memory in the process (glibc mallopt)."""
import platform

from pcdet_memslidar.sim.memory import keep_freed_memory


def test_keep_freed_memory_takes_effect_under_glibc():
    expected = platform.system() == "Linux" and platform.libc_ver()[0] == "glibc"
    assert keep_freed_memory() is expected
