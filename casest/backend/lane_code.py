"""C source of a per-sample SX function summed over samples, a candidate per SIMD lane.

Stage 1 evaluates the same per-sample function at thousands of parameter candidates. CasADi's
generated code runs it as scalar C, one candidate and one sample at a time, with scalar
``sin``/``cos`` calls. Here the function's instruction list (``Function.instruction_*``) is
written as C on GCC/Clang vector types as wide as the CPU's vectors: eight doubles where the
compiler targets AVX-512 (``-march=native`` on such a CPU), four otherwise. Each lane holds one
candidate, the per-sample data are broadcast to the lanes, and the elementary functions are the
vector variants of glibc's libmvec (AVX-512 or AVX2, at most 4 ulp from the correctly rounded
value), or lane by lane through libm where those are not available. The width is decided when
the library is compiled (the compile cache is per CPU) and the library reports it
(``<name>_lanes()``). The sum over samples is accumulated per lane in sample order, as the
serial map-reduce does.
"""

from __future__ import annotations

import casadi as ca

__all__ = ["lane_source"]

_BINARY = {ca.OP_ADD: "({a}+{b})", ca.OP_SUB: "({a}-{b})", ca.OP_MUL: "({a}*{b})", ca.OP_DIV: "({a}/{b})",
           ca.OP_LT: "vbool((vl)({a}<{b}))", ca.OP_LE: "vbool((vl)({a}<={b}))", ca.OP_EQ: "vbool((vl)({a}=={b}))",
           ca.OP_NE: "vbool((vl)({a}!={b}))", ca.OP_AND: "vbool((vl)({a}!=0)&(vl)({b}!=0))",
           ca.OP_OR: "vbool((vl)({a}!=0)|(vl)({b}!=0))", ca.OP_IF_ELSE_ZERO: "vsel((vl)({a}!=0),{b})",
           ca.OP_POW: "VPOW({a},{b})", ca.OP_CONSTPOW: "VPOW({a},{b})", ca.OP_ATAN2: "VATAN2({a},{b})",
           ca.OP_HYPOT: "VHYPOT({a},{b})", ca.OP_FMIN: "lw2(fmin,{a},{b})", ca.OP_FMAX: "lw2(fmax,{a},{b})",
           ca.OP_FMOD: "lw2(fmod,{a},{b})", ca.OP_COPYSIGN: "lw2(copysign,{a},{b})",
           ca.OP_REMAINDER: "lw2(remainder,{a},{b})"}
_UNARY = {ca.OP_ASSIGN: "{a}", ca.OP_NEG: "(-{a})", ca.OP_TWICE: "({a}+{a})", ca.OP_SQ: "({a}*{a})",
          ca.OP_INV: "(1.0/{a})", ca.OP_NOT: "vbool((vl)({a}==0))", ca.OP_FABS: "vabs({a})",
          ca.OP_SQRT: "VSQRT({a})", ca.OP_SIGN: "lw1(csign,{a})", ca.OP_FLOOR: "lw1(floor,{a})",
          ca.OP_CEIL: "lw1(ceil,{a})"}
# elementary functions with AVX2 and AVX-512 variants in libmvec (glibc >= 2.22 for the first five, 2.35 for the rest)
_MVEC_UNARY = {ca.OP_SIN: "sin", ca.OP_COS: "cos", ca.OP_EXP: "exp", ca.OP_LOG: "log", ca.OP_TAN: "tan",
               ca.OP_ASIN: "asin", ca.OP_ACOS: "acos", ca.OP_ATAN: "atan", ca.OP_SINH: "sinh",
               ca.OP_COSH: "cosh", ca.OP_TANH: "tanh", ca.OP_ASINH: "asinh", ca.OP_ACOSH: "acosh",
               ca.OP_ATANH: "atanh", ca.OP_ERF: "erf", ca.OP_LOG1P: "log1p", ca.OP_EXPM1: "expm1"}
_MVEC_BINARY = ("pow", "atan2", "hypot")

_PRELUDE = r"""
#include <math.h>
#include <string.h>
#if defined(__AVX512F__) && !defined(CASEST_LANES4)
#define W 8
#else
#define W 4
#endif
typedef double vd __attribute__((vector_size(8 * W)));
typedef long long vl __attribute__((vector_size(8 * W)));
static inline vd bc(double d) { vd r; for (int i = 0; i < W; ++i) r[i] = d; return r; }
static inline vd vload(const double* p) { vd r; memcpy(&r, p, sizeof r); return r; }
static inline void vstore(double* p, vd x) { memcpy(p, &x, sizeof x); }
static inline vd vbool(vl m) { return (vd)(m & (vl)bc(1.0)); }
static inline vd vsel(vl m, vd x) { return (vd)(m & (vl)x); }
static inline vd vabs(vd x) { vl m; for (int i = 0; i < W; ++i) m[i] = 0x7fffffffffffffffLL; return (vd)((vl)x & m); }
static inline double csign(double x) { return x < 0 ? -1.0 : (x > 0 ? 1.0 : x); }
static inline vd lw1(double (*f)(double), vd a) {
  vd r; for (int i = 0; i < W; ++i) r[i] = f(a[i]); return r;
}
static inline vd lw2(double (*f)(double, double), vd a, vd b) {
  vd r; for (int i = 0; i < W; ++i) r[i] = f(a[i], b[i]); return r;
}
/* lane by lane, vectorised by the compiler (-fno-math-errno): immintrin.h takes 0.6 s of a 0.7 s compile */
static inline vd VSQRT(vd a) { vd r; for (int i = 0; i < W; ++i) r[i] = __builtin_sqrt(a[i]); return r; }
"""


def _function_macros(unary: set, binary: set) -> str:
    """Vector elementary functions: libmvec's AVX-512 or AVX2 variants, else lane by lane
    (CASEST_LANEWISE)."""
    lines = []
    # libmvec's names: _ZGV, the ISA (e: AVX-512, d: AVX2), N and the lanes, a v per argument
    for guard, isa, width in (("#if W == 8 && defined(__x86_64__) && !defined(CASEST_LANEWISE)", "e", 8),
                              ("#elif W == 4 && defined(__AVX2__) && defined(__x86_64__) && !defined(CASEST_LANEWISE)",
                               "d", 4)):
        lines.append(guard)
        lines += [f"extern vd _ZGV{isa}N{width}v_{f}(vd);\n#define V{f.upper()}(a) _ZGV{isa}N{width}v_{f}(a)"
                  for f in sorted(unary)]
        lines += [f"extern vd _ZGV{isa}N{width}vv_{f}(vd, vd);\n#define V{f.upper()}(a, b) _ZGV{isa}N{width}vv_{f}(a, b)"
                  for f in sorted(binary)]
    lines.append("#else")
    lines += [f"#define V{f.upper()}(a) lw1({f}, a)" for f in sorted(unary)]
    lines += [f"#define V{f.upper()}(a, b) lw2({f}, a, b)" for f in sorted(binary)]
    lines.append("#endif")
    return "\n".join(lines)


def _constant(value: float) -> str:
    if value != value:
        return "bc(NAN)"
    if value in (float("inf"), float("-inf")):
        return "bc(INFINITY)" if value > 0 else "bc(-INFINITY)"
    return f"bc({value!r})"


def _body(fun: ca.Function, n_data: int, offsets: list[int], summed: bool) -> tuple[list[str], set, set] | None:
    """The statements of one sample (work variables ``w<k>``), the libmvec functions used; None if an
    instruction has no vector form here (a call to another function, say)."""
    lines, unary, binary = [], set(), set()
    for k in range(fun.n_instructions()):
        op, ins, outs = fun.instruction_id(k), fun.instruction_input(k), fun.instruction_output(k)
        if op == ca.OP_INPUT:
            arg, nz = ins
            src = f"bc(D[{offsets[arg] + nz}])" if arg < n_data else f"P[{offsets[arg] + nz}]"
            lines.append(f"w{outs[0]} = {src};")
        elif op == ca.OP_OUTPUT:
            lines.append(f"acc[{outs[1]}] += w{ins[0]};" if summed else f"vstore(O + W * {outs[1]}, w{ins[0]});")
        elif op == ca.OP_CONST:
            lines.append(f"w{outs[0]} = {_constant(fun.instruction_constant(k))};")
        elif op in _UNARY:
            lines.append(f"w{outs[0]} = {_UNARY[op].format(a=f'w{ins[0]}')};")
        elif op in _MVEC_UNARY:
            unary.add(_MVEC_UNARY[op])
            lines.append(f"w{outs[0]} = V{_MVEC_UNARY[op].upper()}(w{ins[0]});")
        elif op in _BINARY:
            text = _BINARY[op]
            binary.update(f for f in _MVEC_BINARY if f"V{f.upper()}(" in text)
            lines.append(f"w{outs[0]} = {text.format(a=f'w{ins[0]}', b=f'w{ins[1]}')};")
        else:
            return None
    return lines, unary, binary


def lane_source(fun: ca.Function, n_data: int, name: str, summed: bool = True) -> str | None:
    """C source of ``name``: the sums over samples of ``fun``'s output (or, with ``summed`` False,
    its value at every sample) for groups of candidates, one per SIMD lane.

    Parameters
    ----------
    fun : casadi.Function
        An SX function of one sample with one dense output column: inputs ``0 .. n_data-1``
        are the sample's data, the others the candidate's values.
    n_data : int
        Number of leading per-sample inputs.
    name : str
        The C function's name.
    summed : bool
        Sum over the samples (``out`` (n_groups, n_out, W)), else every sample's values
        (``out`` (n_groups, N, n_out, W)), with W the lanes per vector.

    Returns
    -------
    str or None
        The source of ``void name(const double* data, long n_samples, const double* lanes,
        long n_groups, double* out)``: ``data`` sample-major (N, sum of the data inputs' sizes),
        ``lanes`` (n_groups, n_candidate_values, W) and ``out`` (n_groups, n_out, W), a
        candidate per lane, and of ``int name_lanes(void)``, which returns W (8 where the
        compiler targets AVX-512, else 4). None when ``fun`` is not an SX function or uses an operation with
        no vector form here; the caller keeps its scalar path then.
    """
    # the C writes output nonzero k at position k: the output must be dense
    if not fun.is_a("SXFunction") or fun.n_out() != 1 or not fun.sparsity_out(0).is_dense():
        return None
    sizes = [fun.nnz_in(k) for k in range(fun.n_in())]
    if any(fun.nnz_in(k) != fun.numel_in(k) for k in range(fun.n_in())):
        return None
    offsets = [sum(sizes[:k]) - (0 if k < n_data else sum(sizes[:n_data])) for k in range(len(sizes))]
    body = _body(fun, n_data, offsets, summed)
    if body is None:
        return None
    lines, unary, binary = body
    n_data_values, n_lane_values, n_out = sum(sizes[:n_data]), sum(sizes[n_data:]), fun.nnz_out(0)
    n_work = 1 + max([int(s.split(" ", 1)[0][1:]) for s in lines if s.startswith("w")] or [0])
    statements = "\n      ".join(lines)
    return f"""{_PRELUDE}
{_function_macros(unary, binary)}
void {name}(const double* restrict data, long n_samples, const double* restrict lanes, long n_groups,
            double* restrict out) {{
  for (long g = 0; g < n_groups; ++g) {{
    vd P[{max(n_lane_values, 1)}], acc[{max(n_out, 1)}];
    for (int j = 0; j < {n_lane_values}; ++j) P[j] = vload(lanes + W * ({n_lane_values} * g + j));
    for (int j = 0; j < {n_out}; ++j) acc[j] = bc(0.0);
    for (long k = 0; k < n_samples; ++k) {{
      const double* D = data + {n_data_values} * k;
      double* O = out + W * {n_out} * (n_samples * g + k);
      (void)O;
      vd {", ".join(f"w{i}" for i in range(n_work))};
      {statements}
    }}
    if ({int(summed)}) memcpy(out + W * {n_out} * g, acc, sizeof(vd) * {n_out});
  }}
}}
int {name}_lanes(void) {{ return W; }}
"""
