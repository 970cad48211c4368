"""lab/fused_sampling.py: the sampled split of the fused kernel's CPU (its parsing and attribution; the perf run
itself needs the Linux perf tool and is exercised by `monte perf --sections sampled`, not here)."""

from monte.lab import fused_sampling as fs

# `perf script -F tid,time,ip,dso` lines as perf 6 prints them (tid, time stamp in seconds, ip, dso)
LINES = """\
  328 100.000100:      7f0c4bfeb105 (/tmp/perf-328.map)
  328 100.000600:      7f0c4b7ae82d (/usr/lib/x86_64-linux-gnu/libm.so.6)
  328 100.001100:      7f0c4aa00010 (/venv/site-packages/embreex.libs/libembree4-4aef3270.so.4)
  328 100.001600:      7f0c4aa00010 (/venv/site-packages/embreex.libs/libembree4-4aef3270.so.4)
  329 100.001700:      7f0c4aa00010 (/venv/site-packages/embreex.libs/libembree4-4aef3270.so.4)
  328 100.002100:      7f0c4c000000 (/root/.pyenv/versions/3.13.0/lib/libpython3.13.so.1.0)
  328 100.009000:      7f0c4aa00010 (/venv/site-packages/embreex.libs/libembree4-4aef3270.so.4)
  328 99.000000:      7f0c4aa00010 (/venv/site-packages/embreex.libs/libembree4-4aef3270.so.4)
not a sample line
""".splitlines()


def test_classify_names_each_shared_object():
    assert fs.classify("(/venv/site-packages/embreex.libs/libembree4-4aef3270.so.4)") == "Embree"
    assert fs.classify("(/usr/lib/x86_64-linux-gnu/libm.so.6)") == "libm"
    assert fs.classify("(/tmp/perf-328.map)") == "compiled kernels (JIT)"
    assert fs.classify("([unknown])") == "compiled kernels (JIT)"
    assert fs.classify("//anon") == "compiled kernels (JIT)"
    assert fs.classify("(/root/.pyenv/versions/3.13.0/lib/libpython3.13.so.1.0)") == "other"
    assert fs.classify("([kernel.kallsyms])") == "other"
    assert fs.classify("(/usr/lib/x86_64-linux-gnu/libmvec.so.1)") == "other"  # not libm itself


def test_parse_and_split_charge_only_samples_inside_a_kernel_call_of_their_thread():
    samples = fs.parse_samples(LINES)
    assert len(samples) == 8 and samples[0] == (328, 100.0001, "(/tmp/perf-328.map)")
    # thread 328 was in the kernel from 100.0 to 100.002; thread 329 never called it; the render ran 100.0-100.005
    kernel, render = fs.split(samples, {328: [(100.0, 100.002)]}, (100.0, 100.005))
    assert kernel == {"Embree": 2, "compiled kernels (JIT)": 1, "libm": 1, "other": 0}
    # the render window holds thread 329's Embree sample and the Python one, not those at 100.009 and 99.0
    assert render == {"Embree": 3, "compiled kernels (JIT)": 1, "libm": 1, "other": 1}


def test_a_sampled_render_charges_embree_and_the_compiled_kernel():
    """The whole tool on a tiny Cornell box, where the Linux perf tool may sample this user's processes."""
    import shutil

    import pytest

    if shutil.which("perf") is None:
        pytest.skip("needs the Linux perf tool")
    try:
        m = fs.measure(resolution=64, spp=8, threads=1, frequency=4000)
    except RuntimeError as e:  # perf refused (perf_event_paranoid, no permission in this container)
        pytest.skip(str(e))
    kernel, render = m["kernel"], m["render"]
    assert m["kernel_calls"] > 0
    assert kernel["Embree"] > 0 and kernel["compiled kernels (JIT)"] > 0
    assert all(kernel[c] <= render[c] for c in fs.CATEGORIES)  # the kernel's calls lie inside the render
