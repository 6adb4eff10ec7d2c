"""experiments/machine.py: what a measurement says of the machine it ran on."""

import platform

from experiments.machine import cpu_model

ZEN3 = "processor\t: 0\nvendor_id\t: AuthenticAMD\ncpu family\t: 25\nmodel\t\t: 1\nmodel name\t: AMD EPYC\n"
ZEN4 = "processor\t: 0\ncpu family\t: 25\nmodel\t\t: 17\nmodel name\t: AMD EPYC\n"


def test_the_cpu_is_named_with_its_generation_and_avx512(tmp_path):
    """Two VMs both called "AMD EPYC" are told apart: by model number and by AVX-512, read from the first
    processor's block only."""
    older, newer = tmp_path / "zen3", tmp_path / "zen4"
    older.write_text(ZEN3 + "flags\t\t: fpu avx2\n\nprocessor\t: 1\nflags\t\t: avx512f\n")
    newer.write_text(ZEN4 + "flags\t\t: fpu avx2 avx512f avx512bw\n")
    assert cpu_model(str(older)) == "AMD EPYC (family 25, model 1, AVX-512 no)"
    assert cpu_model(str(newer)) == "AMD EPYC (family 25, model 17, AVX-512 yes)"
    assert cpu_model(str(tmp_path / "missing")) == (platform.processor() or "unknown")
