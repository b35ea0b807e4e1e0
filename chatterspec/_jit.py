"""The compiled-kernel switch for per-sample recursions.

Every recursion that cannot be vectorized in time (the smoothing SVSF, the
Kalman family, the second-order SVSF, multiple-model banks) is written once as
a plain function over explicit scalar loops and decorated with :func:`njit`.
With numba installed, :func:`njit` compiles it on first call
(``cache=True``: the machine code is stored beside the source, in
``__pycache__/*.nbi|*.nbc``, so a second process loads it instead of
recompiling); without numba, or with ``CHATTERSPEC_JIT=0`` in the environment,
the caller takes its numpy path instead (see :func:`enabled`). numba is
imported lazily, by the first :func:`enabled` call, so commands that never reach
a kernel do not pay its import time; a numba that is installed but fails to
import means the numpy path, with a warning.

Steps, loops and specializations
--------------------------------
The arithmetic of a filter or a plant is written **once**, as a *step* (:func:`step`): one sample
of one realization, scalar loops over channels, writing into arrays it is given. *Loops* (kernels,
:func:`njit`) iterate runs and samples and call steps; numba inlines every step into every loop
that calls it, so a loop built from steps runs like one written out by hand. A loop that works
for several plants or filters is a *template*: it calls steps by global names it does not define
(``PLANT``, ``SAMPLE``, ...) and reads sizes ``NX``, ``NZ``; :func:`specialize` (or
:func:`specialize_sizes`) binds them, at compile time, for one plant and filter. Small sizes bound
as literals let LLVM unroll the channel loops and keep the per-run state in registers: the EHA's
3-state loops run as fast as the copies written out for 3 states that they replace.

Three things make that true, and the first attempts at sharing steps (1.6-1.8x slower) missed them:

* **No reference counting in the inner loop.** Every array a loop passes to an inlined step costs
  an atomic increment and decrement of its reference count per call when the step has loops of
  run-time length (numba cannot prune them): three times the arithmetic of an SVSF step. A loop
  therefore borrows its array arguments at its top (:func:`borrow`) and keeps its per-run state in
  stack arrays (:func:`scratch`, :func:`scratch2`, :func:`scratch_block`), which have no count.
* **No function values.** A step passed as an argument is typed per function object and defeats
  numba's cache (a new machine-code file per process); a closure over it does too. Bindings are
  global names of a copy of the template, so the compiled loop is cached per binding.
* **A digest in every compiled name.** numba stamps its cache with the source file of the function
  it compiles, not of the steps inlined into it; each kernel's name carries a digest of its code,
  its bound values and every kernel or step it reaches, so editing a step recompiles its loops.

How to add a compiled kernel
----------------------------
1. **Signature.** Arrays and scalars only (no dataclasses, no ``None``: pass an empty array,
   e.g. ``np.empty((0, 0, 0))``, for an output that is not wanted, and test ``out.shape[0] > 0``
   inside). Inputs first, then the state arrays it updates in place, then the preallocated
   outputs. Arrays keep the package layout ``(runs, K, channels)``.
2. **Body.** Borrow the arrays; allocate the per-run state with :func:`scratch` before the loops
   (sizes within :data:`STACK_CAPACITY`, or :func:`fits` in the Python caller); ``for r in
   range(runs):`` outermost, then ``for k in range(K):``, calling the steps. Use only ``+ - * /``,
   ``abs``, ``min``, ``max``, ``np.sign``, ``np.sqrt``, ``np.log``: each is correctly rounded and
   numba does not fuse or reorder them (no ``fastmath``), so the bits depend only on the order of
   the sums. Runs are independent, so a chunk of runs or of samples gives the same bits. Steps and
   kernels are called by their names (``from .x import step``), not as module attributes.
3. **Dispatch.** In the public method, after validating the input in Python, branch on
   :func:`enabled`: compiled kernel if true, the numpy path otherwise (keep it: it is the fallback
   without numba and the baseline of the benchmarks).
4. **Tests.** The compiled path against the numpy path (bit-identical where both sum in the same
   order, else a stated tolerance with its reason), the kernel's Python function
   (``kernel.py_func``) on a tiny input, and every new step against an independent hand formula
   (``tests/test_steps.py``): a wrong step is wrong on both paths.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import threading
import types
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, Literal, TypeVar, cast

import numpy as np

__all__ = [
    "BLOCK_CAPACITY",
    "HAVE_NUMBA",
    "MAX_DIMENSION",
    "STACK_CAPACITY",
    "borrow",
    "enabled",
    "fits",
    "njit",
    "numpy_path",
    "scratch",
    "scratch2",
    "scratch_block",
    "specialize",
    "specialize_sizes",
    "step",
]


F = TypeVar("F", bound=Callable[..., Any])
#: numba's ``error_model`` of a kernel (:func:`specialize`).
ErrorModel = Literal["python", "numpy"]

#: Room (floats) of a compiled :func:`scratch` / :func:`scratch2` whose size is known only at run time.
STACK_CAPACITY = 256
#: Largest number of states or outputs of a loop with matrix scratch (16 x 16 = STACK_CAPACITY).
MAX_DIMENSION = 16
#: Room (floats) of a compiled :func:`scratch_block` (a covariance filter's workspace up to MAX_DIMENSION).
BLOCK_CAPACITY = 8192

#: Whether numba is installed (checked without importing it).
HAVE_NUMBA = importlib.util.find_spec("numba") is not None


_IMPORTABLE: list[bool] = []  # memo of the one import attempt
_THIS_MODULE = __import__("sys").modules[__name__]


def _numba_importable() -> bool:
    """Import numba once; an installed but broken numba (e.g. built for another numpy) means no."""
    if not _IMPORTABLE:
        try:
            import numba  # noqa: F401

            _IMPORTABLE.append(True)
        except Exception as exc:  # pragma: no cover - depends on the environment
            warnings.warn(
                f"numba is installed but cannot be imported ({type(exc).__name__}: {exc}); "
                "chatterspec uses its numpy path",
                RuntimeWarning,
                stacklevel=3,
            )
            _IMPORTABLE.append(False)
    return _IMPORTABLE[0]


def enabled() -> bool:
    """True when compiled kernels are used (numba importable and ``CHATTERSPEC_JIT`` is not ``0``).

    The environment is read at every call, so a test can switch paths with
    ``monkeypatch.setenv``; numba itself is imported on the first call that needs it.
    """
    return (
        HAVE_NUMBA
        and not getattr(_FORCED, "numpy", False)
        and os.environ.get("CHATTERSPEC_JIT", "1") != "0"
        and _numba_importable()
    )


_FORCED = threading.local()


@contextmanager
def numpy_path() -> Iterator[None]:
    """Within the block (this thread only), :func:`enabled` is False: the numpy path runs.

    Used to re-run a chunk whose compiled kernel stopped on a non-finite covariance, so that the
    numpy path (same numbers) can locate the first non-finite sample.
    """
    before = getattr(_FORCED, "numpy", False)
    _FORCED.numpy = True
    try:
        yield
    finally:
        _FORCED.numpy = before


def scratch(n: int) -> np.ndarray:
    """Scratch vector of ``n`` floats for a kernel's per-run state (uninitialized).

    In Python this is ``np.empty(n)``. In a compiled kernel it lives on the stack of the
    compiled function that calls it (no allocation, no reference count): exactly ``n`` floats
    when ``n`` is a compile-time constant (a literal bound by :func:`specialize`, e.g. ``NX =
    3``), where with the steps inlined and their loops unrolled LLVM keeps it in registers;
    :data:`STACK_CAPACITY` floats' room otherwise, of which it uses ``n``: the Python caller
    keeps ``n`` within it (:func:`fits`). Each call site has its own memory, valid until that
    function returns: allocate in the loop, before its loops, or in a step inlined into it, and
    never return it from a compiled function of its own.
    """
    return np.empty(n)


def scratch2(n: int, m: int) -> np.ndarray:
    """Scratch ``(n, m)`` C-order matrix: :func:`scratch` for matrices (``n m <= STACK_CAPACITY``)."""
    return np.empty((n, m))


def scratch_block(n: int) -> np.ndarray:
    """Scratch vector with :data:`BLOCK_CAPACITY` floats' room (a workspace carved into views)."""
    return np.empty(n)


def fits(n: int, m: int = 0, *, vectors_only: bool = False) -> bool:
    """Whether a loop with ``n`` states and ``m`` outputs fits the compiled scratch (else: numpy path).

    Matrices of scratch need ``n, m <= MAX_DIMENSION``; with ``vectors_only`` (the SVSF, the
    simulation) ``n, m <= STACK_CAPACITY``.
    """
    limit = STACK_CAPACITY if vectors_only else MAX_DIMENSION
    return 0 <= n <= limit and 0 <= m <= limit


def borrow(a: Any) -> Any:
    """``a`` itself; in compiled code, the same array without its reference count.

    Every array a compiled loop hands to an inlined step costs numba an atomic increment and
    decrement of its reference count per call, which numba cannot prune when the step has loops
    of run-time length: three times the arithmetic of an SVSF step. A loop therefore borrows its
    array arguments once, at its top (the caller holds them for the whole call), and passes the
    borrowed arrays (and views of them) to its steps. Never borrow an array the kernel itself
    allocates on the heap: nothing would keep it alive.
    """
    return a


#: The lines of numba's ``InlineWorker.inline_ir`` that copy a callee's IR a block at a time, each
#: block with a memo of its own, and the lines :func:`inline_copy` puts in their place (one memo; as
#: many lines, so that numba's line numbers hold).
_PER_BLOCK_COPY = (
    "        kernel_copy.blocks = {}\n"
    "        for block_label, block in the_ir.blocks.items():\n"
    "            new_block = copy.deepcopy(the_ir.blocks[block_label])\n"
)
_ONE_MEMO_COPY = (
    "        kernel_copy.blocks, memo = {}, {}\n"
    "        for block_label, block in the_ir.blocks.items():\n"
    "            new_block = copy.deepcopy(the_ir.blocks[block_label], memo)\n"
)
_INLINE_COPY: list[str] = []  # memo of the one attempt


def inline_copy() -> Literal["one memo", "numba"]:
    """Make numba copy an inlined step's IR in linear time, once per process; which copy is in use.

    Every step reaches its loops through numba's ``inline="always"``, whose ``InlineWorker.inline_ir``
    deep-copies the callee's IR at each call site, one block at a time with a fresh memo. Every
    variable of a function refers to the function's one scope, which lists all its variables, so each
    block's copy copies the whole scope again: a copy costs blocks x variables, and a loop whose
    inlined steps inline steps of their own spent about two thirds of its compilation there (a cold
    SVSF-cov lane loop: 41 of 65 s of CPU, 16 million ``deepcopy`` calls). One memo for all the
    blocks of a copy gives the blocks one copied scope, as they share one scope in the IR copied;
    the compiled code is the same (``tests/test_jit.py`` compares the LLVM IR and the assembly of
    both), the copies take linear time (that loop: 25 s of CPU in all).

    The fix is applied by compiling numba's own source of the method with those two lines changed;
    where the source is not available or the lines differ (another numba release), numba's method
    stays, and so does ``CHATTERSPEC_INLINE_COPY=numba`` in the environment.

    Returns
    -------
    {"one memo", "numba"}
        The copy the inliner uses.
    """
    if not _INLINE_COPY:
        _INLINE_COPY.append(_one_memo_inline_copy())
    return cast(Literal["one memo", "numba"], _INLINE_COPY[0])


def _one_memo_inline_copy() -> str:
    """Install the one-memo copy in numba's inliner (:func:`inline_copy`); the copy then in use."""
    if os.environ.get("CHATTERSPEC_INLINE_COPY", "") == "numba":
        return "numba"
    import inspect
    import linecache
    import textwrap

    from numba.core import inline_closurecall

    worker = inline_closurecall.InlineWorker
    method = worker.inline_ir
    # the method's lines straight from its file (inspect.getsource would first search sys.modules)
    filename, first = method.__code__.co_filename, method.__code__.co_firstlineno
    lines = linecache.getlines(filename)[first - 1 :]
    if not lines:  # pragma: no cover - numba installed without its sources
        return "numba"
    source = textwrap.dedent("".join(inspect.getblock(lines)))
    if source.count(_PER_BLOCK_COPY) != 1 or method.__code__.co_freevars:
        return "numba"
    # blank lines first: a traceback names the lines of numba's file
    code = compile("\n" * (first - 1) + source.replace(_PER_BLOCK_COPY, _ONE_MEMO_COPY), filename, "exec")
    body = next(c for c in code.co_consts if isinstance(c, types.CodeType) and c.co_name == method.__name__)
    patched = types.FunctionType(body, vars(inline_closurecall), method.__name__, method.__defaults__)
    patched.__qualname__, patched.__doc__ = method.__qualname__, method.__doc__
    patched.__module__ = method.__module__
    setattr(worker, method.__name__, patched)  # numba's method, its copies with one memo
    return "one memo"


_FORMS: list[types.ModuleType] = []  # memo of the compiled forms (built once, when numba first compiles)


def _compiled_forms() -> types.ModuleType:
    """The compiled forms of :func:`scratch`, :func:`scratch2`, :func:`scratch_block` and :func:`borrow`.

    numba intrinsics, built (and numba imported) only when a kernel is first compiled: a kernel's
    compiled copy gets them in place of the Python functions it imported by name, and this
    namespace in place of the module when it calls them as ``_jit.scratch(n)``, so ``scratch(n)`` in
    a loop is a stack array. A literal size gives an array of exactly that size (LLVM promotes it to
    registers once the loops over it are unrolled); a run-time size gives the room of
    :data:`STACK_CAPACITY` floats (``scratch_block``: :data:`BLOCK_CAPACITY`), of which the array
    uses the first ``n`` (``n m``): callers keep the sizes within it (:func:`fits`). The memory
    belongs to the frame of the compiled function that calls the intrinsic (the loop, or the step
    inlined into it) and is valid until that function returns: never return it.

    The typing and code-generation callbacks receive numba's own (untyped) context, builder and
    type objects, hence their ``Any`` annotations.
    """
    if _FORMS:
        return _FORMS[0]
    from numba import types as nb
    from numba.core import cgutils
    from numba.extending import intrinsic

    f8 = nb.float64

    def array(context: Any, builder: Any, ptr: Any, shape: list[Any], ndim: int) -> Any:
        """A C-order float64 array of ``shape`` (intp values) at ``ptr``, without a meminfo."""
        arrty = nb.Array(f8, ndim, "C")
        ary = context.make_array(arrty)(context, builder)
        itemsize = context.get_constant(nb.intp, 8)
        strides = [itemsize]
        for s in reversed(shape[1:]):
            strides.insert(0, builder.mul(strides[0], s))
        context.populate_array(
            ary,
            data=ptr,
            shape=cgutils.pack_array(builder, list(shape)),
            strides=cgutils.pack_array(builder, strides),
            itemsize=itemsize,
            meminfo=None,
        )
        return ary._getvalue()

    def stack(capacity: int, ndim: int) -> Callable[..., Any]:
        """Codegen of a stack array: ``capacity`` floats when a size is not literal, else their product."""

        def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
            sizes = signature.args
            if all(isinstance(t, nb.IntegerLiteral) for t in sizes):
                room = 1
                for t in sizes:
                    room *= max(int(t.literal_value), 1)
            else:
                room = capacity
            ptr = cgutils.alloca_once(builder, context.get_value_type(f8), size=room)
            shape = [context.cast(builder, v, t, nb.intp) for v, t in zip(args, sizes, strict=True)]
            return array(context, builder, ptr, shape, ndim)

        return codegen

    @intrinsic
    def scratch(typingctx: Any, n: Any) -> Any:
        """Stack vector of ``n`` floats (see :func:`_compiled_forms`)."""
        if not isinstance(n, nb.Integer):
            return None
        return nb.Array(f8, 1, "C")(n), stack(STACK_CAPACITY, 1)

    @intrinsic
    def scratch2(typingctx: Any, n: Any, m: Any) -> Any:
        """Stack ``(n, m)`` C-order matrix (see :func:`_compiled_forms`)."""
        if not (isinstance(n, nb.Integer) and isinstance(m, nb.Integer)):
            return None
        return nb.Array(f8, 2, "C")(n, m), stack(STACK_CAPACITY, 2)

    @intrinsic
    def scratch_block(typingctx: Any, n: Any) -> Any:
        """Stack vector with the room of ``BLOCK_CAPACITY`` floats (a workspace carved into pieces)."""
        if not isinstance(n, nb.Integer):
            return None

        def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
            ptr = cgutils.alloca_once(builder, context.get_value_type(f8), size=BLOCK_CAPACITY)
            shape = [context.cast(builder, args[0], signature.args[0], nb.intp)]
            return array(context, builder, ptr, shape, 1)

        return nb.Array(f8, 1, "C")(n), codegen

    @intrinsic
    def borrow(typingctx: Any, a: Any) -> Any:
        """The same array without its meminfo (no reference counting); anything else unchanged."""
        if not isinstance(a, nb.Array):

            def identity(context: Any, builder: Any, signature: Any, args: Any) -> Any:
                return args[0]

            return a(a), identity

        def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
            src = context.make_array(a)(context, builder, value=args[0])
            dst = context.make_array(a)(context, builder)
            context.populate_array(
                dst, data=src.data, shape=src.shape, strides=src.strides, itemsize=src.itemsize, meminfo=None
            )
            return dst._getvalue()

        return a(a), codegen

    forms = types.ModuleType(f"{__name__}.compiled_forms", _compiled_forms.__doc__)
    for name, value in {
        "scratch": scratch,
        "scratch2": scratch2,
        "scratch_block": scratch_block,
        "borrow": borrow,
        "STACK_CAPACITY": STACK_CAPACITY,
        "MAX_DIMENSION": MAX_DIMENSION,
        "BLOCK_CAPACITY": BLOCK_CAPACITY,
    }.items():
        setattr(forms, name, value)
    _FORMS.append(forms)
    return forms


def _code_digest(code: types.CodeType, h: Any) -> None:
    h.update(code.co_code)
    h.update(repr(code.co_names).encode())
    for c in code.co_consts:
        if isinstance(c, types.CodeType):
            _code_digest(c, h)
        else:
            h.update(repr(c).encode())


class _LazyKernel:
    """A kernel compiled by numba on its first call (``cache=True, nogil=True``; steps: ``inline="always"``).

    ``py_func`` is the plain Python function (with the :func:`specialize` bindings among its
    globals). Compilation gives numba a copy of it whose globals hold the compiled dispatchers of
    the kernels and steps it names, and whose name carries a digest of its own code, of the
    bound values and of every kernel or step it reaches: numba's cache is stamped only with the
    source file of the function it compiles, so without the digest a loop would keep running
    a step from another file as it was when the loop was first cached.
    """

    __slots__ = ("__name__", "_compiled", "_digest", "_error_model", "_inline", "_python", "py_func")

    def __init__(
        self, func: Callable[..., Any], inline: bool = False, error_model: ErrorModel = "python"
    ) -> None:
        self.py_func = func
        self.__name__ = func.__name__
        self._inline = inline
        self._error_model = error_model
        self._compiled: Callable[..., Any] | None = None
        self._digest: str | None = None
        self._python: Callable[..., Any] | None = None

    def _names(self) -> list[str]:
        names: list[str] = []

        def walk(code: types.CodeType) -> None:
            names.extend(code.co_names)
            for c in code.co_consts:
                if isinstance(c, types.CodeType):
                    walk(c)

        walk(self.py_func.__code__)
        return names

    def digest(self) -> str:
        """Hex digest of this kernel's code, its bound constants and every kernel it calls."""
        if self._digest is None:
            h = hashlib.sha256()
            _code_digest(self.py_func.__code__, h)
            if self._error_model != "python":  # (the default leaves every other kernel's digest as it was)
                h.update(self._error_model.encode())
            env = self.py_func.__globals__
            for name in sorted(set(self._names())):
                dep = env.get(name)
                if isinstance(dep, _LazyKernel):
                    h.update(f"{name}={dep.digest()}".encode())
                elif isinstance(dep, bool | int | float | str):
                    h.update(f"{name}={dep!r}".encode())
            self._digest = h.hexdigest()[:12]
        return self._digest

    def python(self) -> Callable[..., Any]:
        """``py_func`` with the kernels and steps it names also in their Python form.

        ``py_func`` alone calls its steps compiled (their dispatchers), which takes scalars only;
        this form runs every step as Python, so a numpy path can call it on rows of realizations.
        """
        if self._python is None:
            func = self.py_func
            env = dict(func.__globals__)
            for name in set(self._names()):
                dep = env.get(name)
                if isinstance(dep, _LazyKernel):
                    env[name] = dep.python()
            copy = types.FunctionType(func.__code__, env, func.__name__, func.__defaults__, func.__closure__)
            copy.__qualname__ = func.__qualname__
            copy.__module__ = func.__module__
            copy.__doc__ = func.__doc__
            self._python = copy
        return self._python

    def dispatcher(self) -> Callable[..., Any]:
        """The numba dispatcher (compiled lazily on first call, or loaded from the cache)."""
        if self._compiled is None:
            import numba

            forms = _compiled_forms()
            inline_copy()
            func = self.py_func
            env = dict(func.__globals__)
            compiled_forms = {id(scratch): forms.scratch, id(scratch2): forms.scratch2}
            compiled_forms.update({id(scratch_block): forms.scratch_block, id(borrow): forms.borrow})
            for name in set(self._names()):
                dep = env.get(name)
                if isinstance(dep, _LazyKernel):
                    env[name] = dep.dispatcher()
                elif dep is _THIS_MODULE:
                    env[name] = forms
                elif id(dep) in compiled_forms:
                    env[name] = compiled_forms[id(dep)]
            copy = types.FunctionType(func.__code__, env, func.__name__, func.__defaults__, func.__closure__)
            copy.__qualname__ = f"{func.__qualname__}__{self.digest()}"
            copy.__module__ = func.__module__
            if self._inline and os.environ.get("CHATTERSPEC_INLINE", "1") == "1":
                self._compiled = numba.njit(inline="always", nogil=True)(copy)
            else:
                self._compiled = numba.njit(cache=True, nogil=True, error_model=self._error_model)(copy)
        return self._compiled

    def __call__(self, *args: Any) -> Any:
        compiled = self._compiled
        if compiled is None:
            compiled = self.dispatcher()
        return compiled(*args)


def python_form(fn: Callable[..., Any]) -> Callable[..., Any]:
    """The plain Python form of a kernel or step, with every step it calls in Python form too.

    Numpy paths call it on ``(channels, runs)`` rows: the same arithmetic, vectorized over
    realizations (a step called from Python otherwise runs compiled, on scalars only).

    Parameters
    ----------
    fn : callable
        A kernel or step (:func:`njit`, :func:`step`, :func:`specialize`) or a plain function.

    Returns
    -------
    callable
        The Python function (``fn`` itself when it is not a compiled kernel or step).
    """
    return fn.python() if isinstance(fn, _LazyKernel) else fn


def njit(func: F) -> F:
    """Mark ``func`` as a compiled kernel (lazily ``numba.njit(cache=True, nogil=True)``).

    Parameters
    ----------
    func : callable
        A module-level function of scalars and numpy arrays written with explicit loops.

    Returns
    -------
    callable
        A wrapper compiling ``func`` on first call (its ``py_func`` attribute is
        ``func``), or ``func`` itself when numba is not installed.

    See Also
    --------
    step : a piece of arithmetic that kernels inline.
    specialize : a kernel built from a loop template and the steps it calls.
    """
    if not HAVE_NUMBA:
        return func
    return cast(F, _LazyKernel(func))  # called like ``func`` (``__call__`` forwards the arguments)


def step(func: F) -> F:
    """Mark ``func`` as a step: arithmetic that compiled loops inline (``numba.njit(inline="always")``).

    A step is the one implementation of a piece of a filter or plant (one sample of eq (4)-(12),
    a plant's transition, ...). Loops call it by name, or get it bound by :func:`specialize`;
    numba inlines it into each loop at compile time, so a loop built from steps runs like one
    written out by hand. Steps take scalars, arrays and indices, write into output arrays and
    return scalars or nothing; they allocate nothing. Called from Python (a test, or a loop's
    ``py_func``) a step runs compiled on its own.

    Parameters
    ----------
    func : callable
        A module-level function written with explicit loops.

    Returns
    -------
    callable
        The lazily compiled step, or ``func`` itself when numba is not installed.

    See Also
    --------
    njit, specialize
    """
    if not HAVE_NUMBA:
        return func
    return cast(F, _LazyKernel(func, inline=True))  # called like ``func``


def specialize(
    template: Callable[..., Any],
    tag: str,
    *,
    inline: bool = False,
    error_model: ErrorModel = "python",
    **bindings: Any,
) -> Callable[..., Any]:
    """A kernel made of the loop ``template`` with some of its global names bound (compile-time dispatch).

    ``template`` is a module-level function that calls steps (and reads constants) by global
    names it does not define, e.g. ``PLANT(...)`` or ``NX``; ``bindings`` gives them (a step, an
    int). The result compiles to a loop specialized for those steps: numba sees them as
    constants and inlines them, so there is no call through a function value and a literal
    ``NX`` lets LLVM unroll the per-channel loops (see :func:`scratch`). One template serves
    every plant and filter that plugs into it; its compiled form is cached per binding.

    Parameters
    ----------
    template : callable
        The loop, a module-level function.
    tag : str
        A short name of this specialization (letters, digits, ``_``), part of the cache file name.
    inline : bool
        Make a step (inlined by the loops that call it, like :func:`step`) instead of a kernel.
    error_model : {"python", "numpy"}
        numba's ``error_model`` of this kernel (steps take their loop's). ``"python"`` (the default of
        every kernel) checks each division for a zero divisor and raises ZeroDivisionError;
        ``"numpy"`` divides as IEEE 754 does (inf or NaN), without the branch, which lets LLVM
        vectorize a loop over lanes. The quotients are the same bits either way; only a loop whose
        divisors are guarded (or whose results are checked) may take ``"numpy"``.
    **bindings
        Global names of ``template`` and their values for this specialization.

    Returns
    -------
    callable
        A kernel like :func:`njit`'s (or a step); without numba, the plain Python function.

    See Also
    --------
    njit, step
    """
    env = dict(template.__globals__)
    env.update(bindings)
    func = types.FunctionType(template.__code__, env, template.__name__, template.__defaults__)
    func.__qualname__ = f"{template.__qualname__}__{tag}"
    func.__module__ = template.__module__
    func.__doc__ = template.__doc__
    if not HAVE_NUMBA:
        return func
    return _LazyKernel(func, inline=inline, error_model=error_model)


#: Largest size :func:`specialize_sizes` binds as a compile-time constant.
MAX_UNROLL = 4

_SIZED: dict[tuple[Any, ...], Callable[..., Any]] = {}


def specialize_sizes(
    template: Callable[..., Any],
    tag: str,
    sizes: dict[str, int],
    *,
    inline: bool = False,
    error_model: ErrorModel = "python",
    **bindings: Any,
) -> Any:
    """:func:`specialize` with the template's size names bound to literals when all are small.

    ``sizes`` maps the template's size names (``NX``, ``NZ``, ...) to this model's sizes; when
    every one is at most :data:`MAX_UNROLL` they are bound as they are (LLVM unrolls the
    per-channel loops and keeps the per-run state in registers), otherwise all to 0 (the
    template reads them from its arrays). One kernel per template, tag, sizes and bindings,
    kept for the process (and numba caches its machine code).

    Parameters
    ----------
    template : callable
        The loop.
    tag : str
        Name of the specialization (the sizes are appended).
    sizes : dict of str to int
        Size names of ``template`` and their values.
    error_model : {"python", "numpy"}
        As :func:`specialize`.
    **bindings
        Other names bound as by :func:`specialize`.

    Returns
    -------
    callable
    """
    small = all(0 <= v <= MAX_UNROLL for v in sizes.values())
    values = {k: (int(v) if small else 0) for k, v in sizes.items()}
    key = (
        template,
        tag,
        inline,
        error_model,
        tuple(sorted(values.items())),
        tuple(sorted((k, id(v)) for k, v in bindings.items())),
    )
    kernel = _SIZED.get(key)
    if kernel is None:
        suffix = "_".join(f"{k.lower()}{v}" for k, v in sorted(values.items()))
        kernel = specialize(
            template, f"{tag}_{suffix}", inline=inline, error_model=error_model, **values, **bindings
        )
        _SIZED[key] = kernel
    return kernel
