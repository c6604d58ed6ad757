"""native.calls: a compiled function called by address gives what its ctypes call gives, for
each signature the loop uses (the master's kernel, the controllers' compiled cycles)."""
import ctypes

import pytest

import native
from native.calls import address_of, load_calls

C_SOURCE = """
#include <string.h>
int p_ll_p(long long *p, long long k, long long *q) { p[0] = k; if (q) q[0] = -k; return (int)(k % 1000) + 1; }
int p_p_p(long long *p, long long *a, long long *b) { p[0] = a ? a[0] : -1; p[1] = b ? b[0] : -1; return 7; }
int p_ll_ll_p(long long *p, long long a, long long b, long long *q) { p[0] = a; p[1] = b; q[0] = a * b; return -3; }
"""


@pytest.fixture(scope="module")
def lib(tmp_path_factory):
    source = tmp_path_factory.mktemp("calls") / "calls_probe.c"
    source.write_text(C_SOURCE)
    lib = native.load_ctypes(native.build("calls_probe", [source]))
    lib.p_ll_p.argtypes = [ctypes.c_void_p, ctypes.c_longlong, ctypes.c_void_p]
    lib.p_p_p.argtypes = [ctypes.c_void_p] * 3
    lib.p_ll_ll_p.argtypes = [ctypes.c_void_p, ctypes.c_longlong, ctypes.c_longlong, ctypes.c_void_p]
    return lib


@pytest.mark.skipif(native.mode() == "off", reason="COSIM_NATIVE=off")
def test_direct_calls_equal_the_ctypes_calls(lib):
    calls = load_calls()
    assert calls is not None
    buffers = [(ctypes.c_longlong * 2)() for _ in range(4)]
    a, b, c, d = (ctypes.addressof(x) for x in buffers)
    for k in (0, 5, -7, 2**40 + 3, -(2**62)):
        assert calls.int_p_ll_p(address_of(lib.p_ll_p), a, k, b) == lib.p_ll_p(c, k, d)
        assert list(buffers[0]) == list(buffers[2]) and list(buffers[1]) == list(buffers[3])
    assert calls.int_p_ll_p(address_of(lib.p_ll_p), a, 9, 0) == lib.p_ll_p(c, 9, None) == 10  # NULL pointer
    buffers[1][0], buffers[3][0] = 11, 11
    assert calls.int_p_p_p(address_of(lib.p_p_p), a, b, None) == lib.p_p_p(c, d, None) == 7
    assert list(buffers[0]) == list(buffers[2]) == [11, -1]
    assert calls.int_p_ll_ll_p(address_of(lib.p_ll_ll_p), a, 6, -4, b) == lib.p_ll_ll_p(c, 6, -4, d) == -3
    assert list(buffers[0]) == list(buffers[2]) == [6, -4] and buffers[1][0] == buffers[3][0] == -24
    with pytest.raises(OverflowError):
        calls.int_p_ll_p(address_of(lib.p_ll_p), a, 2**64, b)
    with pytest.raises(TypeError):
        calls.int_p_p_p(address_of(lib.p_p_p), a, b)
