"""Which names may become C identifiers of the generated firmware.

Joint and sensor names of the artefact and the ``--prefix`` are spliced into identifiers:

| source | identifiers (prefix ``p``, ``P`` = upper case) |
|---|---|
| prefix | ``p_real``, ``p_siso_*``, ``p_clqg_*``, ``p_can_*``, ``P_STATUS_*``, ``P_CAN_*``, file names |
| joint ``j`` | ``P_{SISO,CLQG}_JOINT_<J>``, ``P_CAN_<F>_{ID,LENGTH}``, ``p_can_{pack,unpack}_<f>``, ``p_can_<f>_t`` |
| sensor ``s`` | ``P_CLQG_SENSOR_<S>``, the member ``<s>`` (lower case) of ``p_can_tip_sensors_t`` |

(``F`` the frames ``JOINT_<J>``, ``SETPOINT_<J>``, ``AMP_STATUS_<J>``, ``f`` their lower case.)

Every identifier but the sensor member carries the prefix and a fixed infix, so a name cannot
be a keyword there; what can break is an underscore (``_x`` or ``x_`` give ``__`` next to the
infix: reserved in C++, which the headers' ``extern "C"`` invites; a leading ``_`` + capital or
``__`` is reserved in C), two names equal but for case (the macros upper-case them), and for the
sensor member: a C or C++ keyword after lower-casing (``double``, ``INT``), an object-like
macro or type name of the standard headers (``errno``, ``stdin``, ``bool``, ``size_t``), and the
frame's own generated signals (the E2E ``crc`` and ``counter``). So names are
``[A-Za-z][A-Za-z0-9]*`` words joined by single underscores, at most :data:`NAME_LENGTH`
characters, and the sensor member is checked against :data:`RESERVED`.
"""

from __future__ import annotations

import re
from collections.abc import Iterable

from smartjoint.common.errors import ModelError

NAME_LENGTH = 32  # keeps identifiers readable; longer DBC symbols get cantools' long-name attributes
PREFIX_LENGTH = 24
NAME = re.compile(r"^[A-Za-z][A-Za-z0-9]*(?:_[A-Za-z0-9]+)*$")
PREFIX = re.compile(r"^[a-z][a-z0-9]*(?:_[a-z0-9]+)*$")
NAME_RULE = (
    "letters and digits, starting with a letter, words joined by single underscores "
    f"([A-Za-z][A-Za-z0-9]*(_[A-Za-z0-9]+)*, at most {NAME_LENGTH} characters)"
)

# C89–C23 keywords (C23's lower-case spellings too: bool, true, false, static_assert, …).
C_KEYWORDS = frozenset(
    """auto break case char const continue default do double else enum extern float for goto if
inline int long register restrict return short signed sizeof static struct switch typedef union unsigned void
volatile while _Alignas _Alignof _Atomic _Bool _Complex _Generic _Imaginary _Noreturn _Static_assert _Thread_local
_BitInt _Decimal32 _Decimal64 _Decimal128 alignas alignof bool constexpr false nullptr static_assert thread_local
true typeof typeof_unqual""".split()
)
# The headers are wrapped in extern "C" for C++ callers: a member named like a C++ keyword breaks them.
CPP_KEYWORDS = frozenset(
    """and and_eq asm bitand bitor catch char8_t char16_t char32_t class co_await co_return
co_yield compl concept const_cast consteval constinit decltype delete dynamic_cast explicit export friend mutable
namespace new noexcept not not_eq operator or or_eq private protected public reinterpret_cast requires static_cast
template this throw try typeid typename using virtual wchar_t xor xor_eq""".split()
)
# Object-like macros and type names of the standard headers the generated code includes (stdint.h,
# stddef.h, math.h, stdio.h in main.c) or a firmware commonly does (errno.h, assert.h, stdbool.h,
# complex.h, stdarg.h, setjmp.h, iso646.h), and GCC's predefined lower-case macros outside strict
# ISO mode (a gnu99 build of `double linux;` reads `double 1;`).
STANDARD_NAMES = frozenset(
    """errno assert stdin stdout stderr offsetof setjmp longjmp va_arg va_start va_end va_copy
va_list jmp_buf complex imaginary noreturn math_errhandling fpclassify isfinite isinf isnan isnormal signbit
isgreater isgreaterequal isless islessequal islessgreater isunordered size_t ptrdiff_t max_align_t wint_t
float_t double_t fpos_t int8_t int16_t int32_t int64_t uint8_t uint16_t uint32_t uint64_t intptr_t uintptr_t
intmax_t uintmax_t int_least8_t int_least16_t int_least32_t int_least64_t uint_least8_t uint_least16_t
uint_least32_t uint_least64_t int_fast8_t int_fast16_t int_fast32_t int_fast64_t uint_fast8_t uint_fast16_t
uint_fast32_t uint_fast64_t linux unix i386""".split()
)
RESERVED = C_KEYWORDS | CPP_KEYWORDS | STANDARD_NAMES
RUNTIME_PREFIX = "sj_e2e"  # the hand-written E2E runtime's names


def check_prefix(prefix) -> None:
    """Refuse a ``--prefix`` that cannot form the generated identifiers.

    Parameters
    ----------
    prefix : str
        A lower-case identifier that cannot form a reserved or runtime name.

    Raises
    ------
    ModelError
        Not a lower-case word sequence of at most :data:`PREFIX_LENGTH` characters, a reserved
        name, or the E2E runtime's own prefix.

    Examples
    --------
    >>> check_prefix("smartjoint")
    """
    if not (isinstance(prefix, str) and PREFIX.match(prefix) and len(prefix) <= PREFIX_LENGTH):
        raise ModelError(
            f"--prefix: {prefix!r} — must be lower-case letters and digits, starting with a letter, "
            f"words joined by single underscores ([a-z][a-z0-9]*(_[a-z0-9]+)*, at most {PREFIX_LENGTH} "
            "characters)"
        )
    if prefix in RESERVED:
        raise ModelError(f"--prefix: {prefix!r} — a C/C++ keyword or standard library name; choose another prefix")
    if prefix == RUNTIME_PREFIX or prefix.startswith(RUNTIME_PREFIX + "_"):
        raise ModelError(
            f"--prefix: {prefix!r} — {RUNTIME_PREFIX}_* names belong to the E2E runtime "
            "(firmware/runtime/sj_e2e.h); choose another prefix"
        )


ARTIFACT_FIELDS = ("joint_names[{}]", "sensor_names[{}]")
DESIGN_FIELDS = ("joints[{}].name", "sensors[{}].name")  # the design file's keys, checked before any work


def check_names(
    joint_names: Iterable[str],
    sensor_names: Iterable[str],
    members: Iterable[str] = (),
    fields: tuple[str, str] = ARTIFACT_FIELDS,
) -> None:
    """Refuse joint and sensor names of an artefact that cannot become C identifiers.

    Parameters
    ----------
    joint_names, sensor_names : iterable of str
        The names (fields ``joint_names[i]``, ``sensor_names[i]``).
    members : iterable of str
        The other members of the sensor frame's struct (the E2E ``crc`` and ``counter``), which a
        sensor member must not repeat.
    fields : tuple of (str, str)
        How errors name the i-th joint and sensor (``DESIGN_FIELDS`` for a design file).

    Raises
    ------
    ModelError
        The first name that breaks a rule of the module docstring, with the rule.

    Examples
    --------
    >>> check_names(["A1", "A2"], ["tip_y"])
    """
    members = tuple(members)
    for kind, names, template in (("joint", tuple(joint_names), fields[0]), ("sensor", tuple(sensor_names), fields[1])):
        seen: dict[str, int] = {}
        for i, name in enumerate(names):
            where = template.format(i)
            if not (isinstance(name, str) and NAME.match(name) and len(name) <= NAME_LENGTH):
                raise ModelError(
                    f"{where}: {name!r} — a {kind} name becomes part of C identifiers: {NAME_RULE}; "
                    f"rename {kind} {name!r} in the design file"
                )
            key = name.upper()
            if key in seen:
                raise ModelError(
                    f"{where}: {name!r} — equal to {template.format(seen[key])} {names[seen[key]]!r} but for "
                    f"case; the generated macros upper-case names, so they must differ in more than case"
                )
            seen[key] = i
            if kind == "sensor":
                member = name.lower()
                if member in RESERVED:
                    raise ModelError(
                        f"{where}: {name!r} — becomes the struct member {member!r} of the CAN layer, a "
                        "C/C++ keyword or standard library name; rename the sensor in the design file"
                    )
                if member in members:
                    raise ModelError(
                        f"{where}: {name!r} — becomes the struct member {member!r} of the CAN layer, "
                        f"which the sensor frame already has (generated: {', '.join(members)}); rename "
                        "the sensor in the design file"
                    )
