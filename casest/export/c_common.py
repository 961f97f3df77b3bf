"""The C every export's wrapper shares: a struct laid out with its size known at export, the status
enum, the memory macros of the header, and the finiteness check, all written to MISRA C:2012's
mandatory and required rules and warning-free under ``-Wall -Wextra -Wpedantic -Wshadow
-Wconversion -Wdouble-promotion``.
"""

from __future__ import annotations

__all__ = ["Member", "struct_c", "struct_bytes", "work_bytes", "WORK_MEMBERS", "status_enum_c", "memory_macros_c", "finite_c", "cholesky_c",
           "literal"]

#: (size, alignment) of the member types on a target with 8-byte and with 4-byte pointers
#: (x86-64 / AArch64, and 32-bit ARM EABI, where 8-byte integers and doubles align to 8)
_TYPES = {"long long": (8, 8), "unsigned long long": (8, 8), "double": (8, 8), "float": (4, 4), "int": (4, 4)}


class Member(tuple):
    """A struct member: ``Member(c_type, name, count, comment)``; ``c_type`` may hold the word
    ``REAL`` (the export's number type) and ends in ``*`` for a pointer; ``count`` None is a
    scalar, else an array of at least one element."""

    def __new__(cls, c_type: str, name: str, count: int | None, comment: str = ""):
        return super().__new__(cls, (c_type, name, None if count is None else max(int(count), 1), comment))


def _size_alignment(c_type: str, pointer_bytes: int, real_bytes: int) -> tuple[int, int]:
    if c_type.endswith("*"):
        return pointer_bytes, pointer_bytes
    if c_type == "REAL":
        return real_bytes, real_bytes
    return _TYPES[c_type]


def struct_bytes(members: list, pointer_bytes: int, real_bytes: int) -> int:
    """The ``sizeof`` of a struct of these members in this order (natural alignment, the struct
    rounded up to its largest member alignment).

    Parameters
    ----------
    members : list of Member
        With ``c_type`` one of long long, unsigned long long, double, float, int, REAL, or a pointer.
    pointer_bytes : int
        4 or 8.
    real_bytes : int
        The export's number type: 8 (double) or 4 (float).

    Returns
    -------
    int
    """
    offset, largest = 0, 1
    for c_type, _, count, _ in members:
        size, alignment = _size_alignment(c_type, pointer_bytes, real_bytes)
        offset = -(-offset // alignment) * alignment + size * (count or 1)
        largest = max(largest, alignment)
    return -(-offset // largest) * largest


#: the members that are CasADi's work arrays (:func:`work_bytes`)
WORK_MEMBERS = ("iw", "w", "arg", "res")


def work_bytes(members: list, pointer_bytes: int, real_bytes: int) -> int:
    """Bytes of the generated code's work arrays among the members (:data:`WORK_MEMBERS`), each
    counted at its own size.

    Parameters
    ----------
    members : list of Member
    pointer_bytes, real_bytes : int

    Returns
    -------
    int
    """
    return sum(struct_bytes([m], pointer_bytes, real_bytes) for m in members if m[1] in WORK_MEMBERS)


def struct_c(type_name: str, members: list, real_type: str) -> str:
    """The ``typedef struct`` of the members.

    Parameters
    ----------
    type_name : str
    members : list of Member
    real_type : str
        The C name that stands for ``REAL`` (e.g. ``fl_real``).

    Returns
    -------
    str
    """
    lines = []
    for c_type, name, count, comment in members:
        declared = c_type.replace("REAL", real_type)
        declared = declared[:-1].rstrip() + " *" if declared.endswith("*") else declared + " "
        array = "" if count is None else f"[{count}]"
        lines.append(f"  {declared}{name}{array};" + (f"  /* {comment} */" if comment else ""))
    return "typedef struct {\n" + "\n".join(lines) + f"\n}} {type_name};"


def status_enum_c(name: str, codes: tuple) -> str:
    """The status enum ``NAME_status_t`` of ``(suffix, value, meaning)`` codes, each documented.

    Parameters
    ----------
    name : str
    codes : tuple of (str, int, str)

    Returns
    -------
    str
    """
    up = name.upper()
    body = "\n".join(f"  {up}_{key} = {value}{',' if i < len(codes) - 1 else ''}  /**< {meaning} */"
                     for i, (key, value, meaning) in enumerate(codes))
    return f"/** What the calls of {name} return. */\ntypedef enum {{\n{body}\n}} {name}_status_t;"


def memory_macros_c(name: str, struct_type: str, sizes64: tuple, sizes32: tuple, stack: dict | None) -> str:
    """The header's ``NAME_STRUCT_BYTES``, ``NAME_WORK_BYTES`` and ``NAME_STACK_BYTES``.

    Parameters
    ----------
    name : str
    struct_type : str
        The struct the sizes are of.
    sizes64, sizes32 : tuple of int
        ``(struct bytes, work bytes)`` with 64-bit and with 32-bit pointers.
    stack : dict or None
        :func:`casest.export.c_memory.stack_use`'s result.

    Returns
    -------
    str
    """
    up = name.upper()
    if stack is None:
        stack_text = f"/* {up}_STACK_BYTES is not defined: no GCC was found at export to measure it. */"
    else:
        stack_text = (f"/** The largest stack a call uses, in bytes ({stack['function']}), measured by\n"
                      f"    {stack['compiler']} with -fstack-usage at export; other compilers and targets differ. */\n"
                      f"#define {up}_STACK_BYTES {stack['bytes']}U")
    return f"""/** Bytes of {struct_type}, its sizeof ({sizes64[0]} with 64-bit pointers, {sizes32[0]} with 32-bit ones). */
#define {up}_STRUCT_BYTES ((sizeof(void *) > 4U) ? {sizes64[0]}U : {sizes32[0]}U)
/** The part of {struct_type} that is the generated code's work arrays. */
#define {up}_WORK_BYTES ((sizeof(void *) > 4U) ? {sizes64[1]}U : {sizes32[1]}U)
{stack_text}"""


def literal(value: str, real: str) -> str:
    """A floating literal in the export's precision (``"0.0"`` or ``"0.0f"``).

    Parameters
    ----------
    value : str
    real : {"double", "float"}

    Returns
    -------
    str
    """
    return value + "f" if real == "float" else value


def finite_c(name: str) -> str:
    """The C of ``static bool NAME_finite(v, n)``: whether the n values of v are all finite.

    Parameters
    ----------
    name : str

    Returns
    -------
    str
    """
    return f"""
/* Whether the n values of v are all finite. */
static bool {name}_finite(const {name}_real *v, int n) {{
  bool all = true;
  int i;
  for (i = 0; i < n; ++i) {{
    if (isfinite(v[i]) == 0) {{
      all = false;
    }}
  }}
  return all;
}}
"""


def cholesky_c(name: str, real: str, semidefinite: bool = False) -> str:
    """The C of ``static bool NAME_cholesky(L, A, m, shift)`` (the Cholesky factor of A + shift I,
    false where A is not symmetric to 1e-7 of sqrt(A_ii A_jj), 1e-4 in single precision, or the
    sum not positive definite), in the export's own precision; with ``semidefinite``, also ``NAME_semidefinite(L, A, m)`` (A + 1e-9 max(A_ii) I
    factorable; 1e-6 in single precision).

    Parameters
    ----------
    name : str
    real : {"double", "float"}
    semidefinite : bool

    Returns
    -------
    str
    """
    zero, tol, tiny = literal("0.0", real), literal("1e-6" if real == "float" else "1e-9", real), \
        literal("1e-30" if real == "float" else "1e-300", real)
    sqrt, fabs = ("sqrtf", "fabsf") if real == "float" else ("sqrt", "fabs")
    symmetry = literal("1e-8" if real == "float" else "1e-14", real)  # the squared relative asymmetry taken
    return f"""
/* The Cholesky factor L of A + shift I (A m x m, column-major), or false where A is not symmetric
   (|A_ij - A_ji| above 1e-7 sqrt(A_ii A_jj), 1e-4 in single precision: a covariance accumulated
   in floating point is symmetric only to its rounding) or the sum not positive definite; in the
   export's own precision. */
static bool {name}_cholesky({name}_real *L, const {name}_real *A, int m, {name}_real shift) {{
  bool ok = true;
  int i;
  int j;
  int k;
  {name}_real diagonal;
  {name}_real value;
  {name}_real asymmetry;
  for (i = 0; i < m; ++i) {{
    for (j = 0; j < i; ++j) {{
      asymmetry = A[i + (j * m)] - A[j + (i * m)];
      if ((asymmetry * asymmetry) > (({symmetry} * {fabs}(A[i + (i * m)] * A[j + (j * m)])) + {tiny})) {{
        ok = false;
      }}
    }}
  }}
  for (j = 0; (j < m) && ok; ++j) {{
    diagonal = A[j + (j * m)] + shift;
    for (k = 0; k < j; ++k) {{
      diagonal -= L[j + (k * m)] * L[j + (k * m)];
    }}
    if (diagonal > {zero}) {{
      L[j + (j * m)] = {sqrt}(diagonal);
      for (i = j + 1; i < m; ++i) {{
        value = A[i + (j * m)];
        for (k = 0; k < j; ++k) {{
          value -= L[i + (k * m)] * L[j + (k * m)];
        }}
        L[i + (j * m)] = value / L[j + (j * m)];
      }}
    }} else {{
      ok = false;
    }}
  }}
  return ok;
}}
""" + (f"""
/* Whether A (m x m) is symmetric positive semidefinite: A + 1e-9 max(A_ii) I factorable. */
static bool {name}_semidefinite({name}_real *L, const {name}_real *A, int m) {{
  {name}_real largest = {zero};
  int i;
  for (i = 0; i < m; ++i) {{
    if (A[i + (i * m)] > largest) {{
      largest = A[i + (i * m)];
    }}
  }}
  return {name}_cholesky(L, A, m, ({tol} * largest) + {tiny});
}}
""" if semidefinite else "")
