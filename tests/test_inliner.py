"""numba's inliner with one copy of a callee's scope per inlining (clothjit._InlinerCopies):
the same machine code as numba's own, the scope copied once instead of once per block, and
nothing of it loaded by a run that only loads kernels from the cache."""
from __future__ import annotations

import subprocess
import sys

from conftest import child_env

# A caller with nested inline="always" callees of several blocks each (branches, a loop),
# run in a fresh interpreter: first with clothpipe's inliner, then with numba's own
# (`InlineWorker.inline_ir.__wrapped__`, numba's `copy`), the same source compiled anew.
_NESTED = '''
import copy, re, sys
import numpy as np
import clothjit as jit
from clothjit import njit

assert "numba.core.inline_closurecall" not in sys.modules  # loaded on the first compile

SOURCE = """
@njit(cache=False, inline="always")
def inner(a, b):
    if a > b:
        return a - b
    s = 0.0
    for i in range(3):
        s += a * i
    return s + b

@njit(cache=False, inline="always")
def middle(a, b):
    if a < 0.0:
        return inner(-a, b) + inner(b, a)
    return inner(a, b) * 2.0

@njit(cache=False)
def outer(x):
    out = 0.0
    for v in x:
        out += middle(v, 0.5) - middle(0.25, v)
    return out
"""


def compiled():
    space = {"njit": njit}
    exec(SOURCE, space)
    kernel = space["outer"]
    x = np.linspace(-2.0, 2.0, 41)
    value = kernel(x)
    asm = kernel.inspect_asm(kernel.signatures[0])
    asm = re.sub(r"_ZN[0-9A-Za-z_]+", "SYM", asm)  # names carry a per-process uid
    asm = "\\n".join(l for l in asm.splitlines() if ".ascii" not in l and ".size" not in l)
    return value, asm


from numba.core import inline_closurecall as inliner

value, patched_asm = compiled()
assert isinstance(inliner.copy, jit._InlinerCopies), type(inliner.copy)
inliner.copy = copy  # numba's own inliner again
inliner.InlineWorker.inline_ir = inliner.InlineWorker.inline_ir.__wrapped__
own_value, own_asm = compiled()
print(value == own_value, patched_asm == own_asm, len(patched_asm) > 1000)
print(repr(value))
'''


def _python_outer(x):
    def inner(a, b):
        if a > b:
            return a - b
        s = 0.0
        for i in range(3):
            s += a * i
        return s + b

    def middle(a, b):
        if a < 0.0:
            return inner(-a, b) + inner(b, a)
        return inner(a, b) * 2.0

    out = 0.0
    for v in x:
        out += middle(v, 0.5) - middle(0.25, v)
    return out


def test_same_machine_code_and_value_as_numbas_own_inliner():
    import numpy as np

    run = subprocess.run([sys.executable, "-c", _NESTED], capture_output=True, text=True,
                         env=child_env(), timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stdout.split("\n")[0].split() == ["True", "True", "True"]
    value = float(run.stdout.split("\n")[1])
    assert value == _python_outer(np.linspace(-2.0, 2.0, 41))


def test_blocks_of_one_inlining_share_one_copy_of_the_scope():
    """Copied block by block with one memo, a function's blocks keep one scope (a new one),
    as in the original IR; numba's own copy (a memo per block) copies it once per block."""
    import copy

    from numba.core import ir
    from numba.core.compiler import run_frontend

    import clothjit as jit

    def branches(a, b):
        if a > b:
            return a - b
        s = 0.0
        for i in range(3):
            s += a * i
        return s + b

    func_ir = run_frontend(branches)
    blocks = list(func_ir.blocks.values())
    assert len(blocks) > 3 and len({id(b.scope) for b in blocks}) == 1
    copies = jit._InlinerCopies()
    copies.memo = {}
    ours = [copies.deepcopy(b) for b in blocks]
    own = [copy.deepcopy(b) for b in blocks]
    assert len({id(b.scope) for b in ours}) == 1 and ours[0].scope is not blocks[0].scope
    assert len({id(b.scope) for b in own}) == len(blocks)
    for original, mine in zip(blocks, ours):
        assert [str(s) for s in mine.body] == [str(s) for s in original.body]
        assert all(isinstance(s, ir.Stmt) for s in mine.body)
    copies.memo = None  # outside an inlining: numba's own copy
    assert copies.deepcopy(blocks[0]).scope is not copies.deepcopy(blocks[1]).scope
