"""What a generated C name must not be: a keyword of C (C99 to C23) or of C++ (the header is
read by C++ too), a name of the C standard library (C11, its maths functions with their ``f``
and ``l`` forms, and the common POSIX ones a libc exports, such as ``y0`` or ``index``), a name
the standard reserves for the library's future (``is``, ``to``, ``str``, ``mem``, ``wcs`` and a
lower-case letter), or a name another export could also define (a prefix nested in another:
``ax`` defines ``ax_eval``, which is the whole of the prefix ``ax_eval``)."""

from __future__ import annotations

import re

from clm_sim.errors import UserError

KEYWORDS = set("""
auto break case char const continue default do double else enum extern float for goto if inline
int long register restrict return short signed sizeof static struct switch typedef union unsigned
void volatile while _Alignas _Alignof _Atomic _Bool _Complex _Generic _Imaginary _Noreturn
_Static_assert _Thread_local alignas alignof bool constexpr false nullptr static_assert
thread_local true typeof typeof_unqual
and and_eq asm bitand bitor catch char8_t char16_t char32_t class compl concept consteval
constinit const_cast co_await co_return co_yield decltype delete dynamic_cast explicit export
friend mutable namespace new noexcept not not_eq operator or or_eq private protected public
reinterpret_cast requires static_cast template this throw try typeid typename using virtual
wchar_t xor xor_eq main
""".split())

_MATH = """
acos asin atan atan2 cos sin tan acosh asinh atanh cosh sinh tanh exp exp2 expm1 frexp ilogb
ldexp log log10 log1p log2 logb modf scalbn scalbln cbrt fabs hypot pow sqrt erf erfc lgamma
tgamma ceil floor nearbyint rint lrint llrint round lround llround trunc fmod remainder remquo
copysign nan nextafter nexttoward fdim fmax fmin fma j0 j1 jn y0 y1 yn gamma drem significand
exp10 pow10 sincos
""".split()
LIBRARY = set(_MATH) | {m + s for m in _MATH for s in ("f", "l")} | set("""
abort abs atexit at_quick_exit atof atoi atol atoll bsearch calloc div exit _Exit free getenv
labs ldiv llabs lldiv malloc mblen mbstowcs mbtowc qsort quick_exit rand realloc srand strtod
strtof strtol strtold strtoll strtoul strtoull system wcstombs wctomb aligned_alloc
memchr memcmp memcpy memmove memset strcat strchr strcmp strcoll strcpy strcspn strerror strlen
strncat strncmp strncpy strpbrk strrchr strspn strstr strtok strxfrm strdup strndup
clearerr fclose feof ferror fflush fgetc fgetpos fgets fopen fprintf fputc fputs fread freopen
fscanf fseek fsetpos ftell fwrite getc getchar gets perror printf putc putchar puts remove
rename rewind scanf setbuf setvbuf snprintf sprintf sscanf tmpfile tmpnam ungetc vfprintf
vprintf vsnprintf vsprintf vscanf vsscanf vfscanf fileno popen pclose
isalnum isalpha isblank iscntrl isdigit isgraph islower isprint ispunct isspace isupper
isxdigit tolower toupper isnan isinf isfinite isnormal signbit fpclassify
asctime clock ctime difftime gmtime localtime mktime strftime time timespec_get
raise signal longjmp setjmp va_arg va_end va_start va_copy errno assert offsetof
localeconv setlocale feclearexcept fegetenv fegetexceptflag fegetround feholdexcept
feraiseexcept fesetenv fesetexceptflag fesetround fetestexcept feupdateenv
index rindex bzero bcopy bcmp ffs read write open close lseek sleep usleep alarm fork pipe
dup dup2 kill wait exec select poll link unlink sync stat fstat access chdir environ optarg
size_t ptrdiff_t wchar_t int8_t int16_t int32_t int64_t uint8_t uint16_t uint32_t uint64_t
intptr_t uintptr_t intmax_t uintmax_t FILE fpos_t clock_t time_t div_t ldiv_t lldiv_t
sig_atomic_t jmp_buf va_list max_align_t float_t double_t
NULL EOF BUFSIZ FILENAME_MAX FOPEN_MAX TMP_MAX SEEK_SET SEEK_CUR SEEK_END RAND_MAX MB_CUR_MAX
EXIT_SUCCESS EXIT_FAILURE HUGE_VAL HUGE_VALF HUGE_VALL INFINITY NAN FP_NAN FP_INFINITE FP_ZERO
FP_SUBNORMAL FP_NORMAL MATH_ERRNO MATH_ERREXCEPT CLOCKS_PER_SEC EDOM ERANGE EILSEQ
CHAR_BIT CHAR_MAX CHAR_MIN INT_MAX INT_MIN LONG_MAX LONG_MIN SCHAR_MAX SCHAR_MIN SHRT_MAX
SHRT_MIN UCHAR_MAX UINT_MAX ULONG_MAX USHRT_MAX LLONG_MAX LLONG_MIN ULLONG_MAX SIZE_MAX
PTRDIFF_MAX PTRDIFF_MIN INTPTR_MAX INTPTR_MIN UINTPTR_MAX
FLT_MAX FLT_MIN FLT_EPSILON FLT_DIG FLT_MANT_DIG FLT_MAX_EXP DBL_MAX DBL_MIN DBL_EPSILON
DBL_DIG DBL_MANT_DIG DBL_MAX_EXP M_PI M_E
""".split())
# The standard's reservations of function names for the library's future: is, to, str, mem or
# wcs and a lower-case letter. (Its macro reservations, such as E and an upper-case letter, hold
# where errno.h and the like are included, which the export's files are not; every macro of an
# export has the prefix and an underscore, and the exact library macros are in LIBRARY.)
_FUTURE = re.compile(r"(is|to|str|mem|wcs)[a-z].*")


def names(text: str, prefix: str) -> set[str]:
    """The identifiers of the generated ``text`` that carry ``prefix`` (as ``prefix...`` or
    ``PREFIX...``)."""
    pattern = re.compile(r"(?<![A-Za-z0-9_])(?:" + re.escape(prefix) + r"(?:_\w*)?|"
                         + re.escape(prefix.upper()) + r"_\w*)(?!\w)")
    return {n for n in pattern.findall(text) if not n.endswith("_")}  # "CLM_FF_*" in prose


def check_names(texts, prefix: str) -> None:
    """Refuse (``UserError``, one line) a ``prefix`` whose generated names (in ``texts``) meet a
    keyword, a library name or a reserved spelling, or could meet the names of an export with a
    shorter prefix (the nested case)."""
    found = set().union(*(names(t, prefix) for t in texts))
    for name in sorted(found):
        if name in KEYWORDS or name in LIBRARY or _FUTURE.fullmatch(name):
            raise UserError(f"--prefix {prefix}: it names {name!r}, a C or C++ keyword or a C "
                            f"library name; choose another")
    upper = prefix.upper()
    lower_suffixes = {n[len(prefix):] for n in found if n.startswith(prefix)}
    upper_suffixes = {n[len(upper):] for n in found if n.startswith(upper)}
    for cut in range(1, len(prefix)):
        inner, tail = prefix[:cut], prefix[cut:]
        if not re.fullmatch(r"[a-z][a-z0-9_]*", inner):
            continue
        clash = [inner + s for s in lower_suffixes
                 if s.startswith(tail) and s[len(tail):] in lower_suffixes]
        clash += [inner.upper() + s for s in upper_suffixes
                  if s.startswith(tail.upper()) and s[len(tail):] in upper_suffixes]
        if clash:
            raise UserError(f"--prefix {prefix}: an export with --prefix {inner} names "
                            f"{min(clash)!r} too (nested prefixes collide); choose one that "
                            f"does not extend another by a name the export defines")
