"""The machine a benchmark names: /proc/cpuinfo's first CPU, with the family, model and vector
instructions that a virtual machine's bare processor name leaves out."""

from __future__ import annotations

import platform

from swarmctl.bench import cpu_id, cpu_model

AMD = """processor\t: 0
vendor_id\t: AuthenticAMD
cpu family\t: 25
model\t\t: 17
model name\t: AMD EPYC
flags\t\t: fpu sse2 avx avx2 avx512f avx512bw avx512_bf16 avx512_vnni

processor\t: 1
vendor_id\t: AuthenticAMD
cpu family\t: 26
model\t\t: 2
model name\t: Some Other CPU
flags\t\t: fpu
"""

XEON = """processor : 0
cpu family : 6
model : 143
model name : Intel(R) Xeon(R) Platinum 8481C CPU @ 2.70GHz
flags : avx2 avx512f amx_tile amx_bf16
"""

ARM = """processor\t: 0
BogoMIPS\t: 50.00
Features\t: fp asimd
CPU implementer\t: 0x41
"""


def test_the_first_cpu_is_named_with_family_model_and_vector_width():
    assert cpu_id(AMD) == {"name": "AMD EPYC", "family": 25, "model": 17, "isa": ["AVX2", "AVX-512", "AVX-512 BF16"]}
    assert cpu_model(AMD) == "AMD EPYC (family 25, model 17; AVX2, AVX-512, AVX-512 BF16)"
    assert cpu_model(XEON) == "Intel(R) Xeon(R) Platinum 8481C CPU @ 2.70GHz (family 6, model 143; AVX2, AVX-512, AMX)"


def test_a_cpuinfo_without_those_fields_still_names_the_machine():
    fallback = platform.processor() or platform.machine()
    assert cpu_id(ARM) == {"name": fallback, "family": None, "model": None, "isa": []}
    assert cpu_model(ARM) == fallback
    assert cpu_model("") == fallback
