"""itnet.cpu: the CPU's instruction sets decide whether training autocasts to bfloat16."""

from pathlib import Path

import pytest

from itnet import cpu

CPUINFO = """processor\t: 0
model name\t: Test Xeon
flags\t\t: fpu sse avx2 avx512f {extra}

processor\t: 1
model name\t: Test Xeon
flags\t\t: fpu sse avx2 avx512f {extra}
"""


def _info(tmp_path: Path, extra: str) -> tuple[str, frozenset[str]]:
    path = tmp_path / f"cpuinfo-{extra or 'plain'}"
    path.write_text(CPUINFO.format(extra=extra))
    return cpu.cpu_info(path)


@pytest.mark.parametrize(
    ("extra", "fast"),
    [("", False), ("avx512_vnni", False), ("avx512_bf16", True), ("amx_bf16 amx_tile", True)],
)
def test_bf16_only_where_the_cpu_has_it(tmp_path, monkeypatch, extra, fast):
    info = _info(tmp_path, extra)
    assert info[0] == "Test Xeon" and "avx512f" in info[1]
    monkeypatch.setattr(cpu, "cpu_info", lambda: info)
    assert cpu.fast_bf16("cpu") is fast
    assert cpu.fast_bf16("cuda") is False  # float32 on a GPU, the paper's recipe
    assert cpu.cpu_description().startswith("Test Xeon")


def test_unreadable_cpuinfo_means_no_flags(tmp_path):
    name, flags = cpu.cpu_info(tmp_path / "missing")
    assert name and flags == frozenset()


def test_allocator_setting_applies_on_glibc():
    assert cpu.keep_large_allocations() is True


@pytest.mark.parametrize(("extra", "fast"), [("", False), ("amx_bf16", True)])
def test_trainers_take_bf16_from_the_cpu_unless_told(tmp_path, monkeypatch, extra, fast):
    import torch

    from itnet.model.optim import prepare_cpu

    info = _info(tmp_path, extra)
    monkeypatch.setattr(cpu, "cpu_info", lambda: info)
    threads = torch.get_num_threads()
    try:
        assert prepare_cpu(1, None) is fast
        assert torch.get_num_threads() == 1
        assert prepare_cpu(0, True) is True and prepare_cpu(0, False) is False
        assert prepare_cpu(0, None, device="cuda") is False
        assert torch.get_num_threads() == 1  # 0: left as it was
    finally:
        torch.set_num_threads(threads)
