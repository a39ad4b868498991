"""Elementary functions that give the same bits on every processor (issue 27): fdlibm in NumPy.

NumPy's float64 `arctan`, `arctan2`, `arcsin`, `tan`, `exp`, `log`, `log10`, `power` and `cbrt`
run processor-specific kernels (SVML where the CPU has AVX-512, the C library elsewhere), and
glibc's `sin`, `cos`, `exp`, `atan`, ... pick an FMA or a non-FMA variant by processor. They
disagree in the last bit for up to 8 % of arguments (NumPy 2.4's AVX-512 arcsin against glibc's;
glibc 2.36's FMA sin against its plain one for 0.07 %: measured under NPY_DISABLE_CPU_FEATURES and
GLIBC_TUNABLES=glibc.cpu.hwcaps=-FMA,-AVX2), and one changed bit of
a route's position changes the bytes of every file after it. The functions here are written with
IEEE 754 additions, multiplications, divisions and square roots only, each correctly rounded and
so the same on any processor, in an order fixed by the code: the bits depend on the arguments
alone.

The algorithms and coefficients are fdlibm's (Sun Microsystems, 1993; the library Java's
StrictMath mandates for the same reason): `__kernel_sin`, `__kernel_cos`, `s_atan.c`,
`e_atan2.c`, `e_asin.c`, `e_exp.c`, `e_log.c`. Vectorised, the branches become selections; the
argument reduction of sin and cos is fdlibm's Cody-Waite reduction by pi/2 in up to three parts
(e_rem_pio2.c's medium range; its first branch, for |x| < 3 pi/4, is the same first step).
Errors are below 1 ulp (fdlibm's bound; tests/test_determinism.py checks them against
long-double references), except `atan2` (atan of a rounded quotient) and `log10` (below 2 ulp)
and `power` (about |y ln x| ulp).

Arguments: float64 arrays (or scalars) of any shape; results have their shape. Domains: `sin`
and `cos` take |x| < 2^19 pi/2 (ValueError beyond, where the three-part reduction loses bits);
`exp` takes x in [-708, 709] (beyond, it would overflow or lose precision: ValueError); `log`,
`log10` and `power` take positive finite x (0 gives -inf, negative NaN, as IEEE's log).
"""

from __future__ import annotations

import numpy as np

# sin, cos: pi/2 in three parts of 33 bits with their tails; 2/pi (fdlibm e_rem_pio2.c)
INV_PIO2 = 6.36619772367581382433e-01
PIO2_1, PIO2_1T = 1.57079632673412561417e+00, 6.07710050650619224932e-11
PIO2_2, PIO2_2T = 6.07710050630396597660e-11, 2.02226624879595063154e-21
PIO2_3, PIO2_3T = 2.02226624871116645580e-21, 8.47842766036889956997e-32
SIN_COEFFICIENTS = (-1.66666666666666324348e-01, 8.33333333332248946124e-03, -1.98412698298579493134e-04,
                    2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10)
COS_COEFFICIENTS = (4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05,
                    -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11)
SIN_COS_LIMIT = 2.0 ** 19 * np.pi / 2.0
# atan (s_atan.c): atan of 0.5, 1, 1.5 and infinity in two parts, and the polynomial
ATAN_HI = np.array([4.63647609000806093515e-01, 7.85398163397448278999e-01, 9.82793723247329054082e-01,
                    1.57079632679489655800e+00])
ATAN_LO = np.array([2.26987774529616870924e-17, 3.06161699786838301793e-17, 1.39033110312309984516e-17,
                    6.12323399573676603587e-17])
ATAN_COEFFICIENTS = (3.33333333333329318027e-01, -1.99999999998764832476e-01, 1.42857142725034663711e-01,
                     -1.11111104054623557880e-01, 9.09088713343650656196e-02, -7.69187620504482999495e-02,
                     6.66107313738753120669e-02, -5.83357013379057348645e-02, 4.97687799461593236017e-02,
                     -3.65315727442169155270e-02, 1.62858201153657823623e-02)
ATAN_BANDS = np.array([0.4375, 0.6875, 1.1875, 2.4375])
ATAN_REDUCTION = np.array([[1.0, 2.0, 1.0, 1.0, 0.0], [0.0, 1.0, 1.0, 1.5, 1.0],    # p, q
                           [1.0, 2.0, 1.0, 1.0, 0.0], [0.0, 1.0, 1.0, 1.5, 1.0]])  # r, s
PI, PI_LO = 3.1415926535897931160e+00, 1.2246467991473531772e-16
# asin (e_asin.c)
PIO2_HI, PIO2_LO, PIO4_HI = 1.57079632679489655800e+00, 6.12323399573676603587e-17, 7.85398163397448278999e-01
ASIN_P = (1.66666666666666657415e-01, -3.25565818622400915405e-01, 2.01212532134862925881e-01,
          -4.00555345006794114027e-02, 7.91534994289814532176e-04, 3.47933107596021167570e-05)
ASIN_Q = (-2.40339491173441421878e+00, 2.02094576023350569471e+00, -6.88283971605453293030e-01,
          7.70381505559019352791e-02)
# exp (e_exp.c) and log (e_log.c): ln 2 in two parts
LN2_HI, LN2_LO, INV_LN2 = 6.93147180369123816490e-01, 1.90821492927058770002e-10, 1.44269504088896338700e+00
EXP_COEFFICIENTS = (1.66666666666666019037e-01, -2.77777777770155933842e-03, 6.61375632143793436117e-05,
                    -1.65339022054652515390e-06, 4.13813679705723846039e-08)
EXP_RANGE = (-708.0, 709.0)
LOG_COEFFICIENTS = (6.666666666666735130e-01, 3.999999999940941908e-01, 2.857142874366239149e-01,
                    2.222219843214978396e-01, 1.818357216161805012e-01, 1.531383769920937332e-01,
                    1.479819860511658591e-01)
INV_LN10 = 4.34294481903251816668e-01
LOW_WORD = np.uint64(0xFFFFFFFF)


def _array(x: np.ndarray | float) -> np.ndarray:
    return np.asarray(x, dtype=np.float64)


def _horner(z: np.ndarray, coefficients: tuple[float, ...]) -> np.ndarray:
    """c0 + z*(c1 + z*(c2 + ...)), innermost first, as fdlibm writes its polynomials."""
    result = coefficients[-2] + z * coefficients[-1]
    for coefficient in coefficients[-3::-1]:
        result = coefficient + z * result
    return result


def _high_word(x: np.ndarray) -> np.ndarray:
    """The upper 32 bits of each float64 (sign, exponent, top of the mantissa), as int64."""
    return (np.asarray(x, dtype=np.float64).view(np.uint64) >> np.uint64(32)).astype(np.int64)


def _with_words(high: np.ndarray, low: np.ndarray) -> np.ndarray:
    """Float64s from their upper and lower 32-bit words."""
    return ((high.astype(np.uint64) << np.uint64(32)) | (low & LOW_WORD)).view(np.float64)


def _kernel_sin(x: np.ndarray, y: np.ndarray, has_tail: np.ndarray) -> np.ndarray:
    """sin(x + y) for |x| <= pi/4, y the tail of a reduced argument (fdlibm __kernel_sin)."""
    s1, *rest = SIN_COEFFICIENTS
    z = x * x
    v = z * x
    r = _horner(z, tuple(rest))
    return np.where(has_tail, x - ((z * (0.5 * y - v * r) - y) - v * s1), x + v * (s1 + z * r))


def _kernel_cos(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """cos(x + y) for |x| <= pi/4 (fdlibm __kernel_cos; qx, x/4 cut to its upper word, keeps the
    subtraction from 1 exact for |x| >= 0.3)."""
    z = x * x
    r = z * _horner(z, COS_COEFFICIENTS)
    high = _high_word(x) & 0x7FFFFFFF
    quarter = _with_words(np.maximum(high - 0x00200000, 0), np.zeros_like(high, dtype=np.uint64))
    qx = np.where(high > 0x3FE90000, 0.28125, quarter)
    near = 1.0 - (0.5 * z - (z * r - x * y))
    far = (1.0 - qx) - ((0.5 * z - qx) - (z * r - x * y))
    return np.where(high < 0x3FD33333, near, far)


def _reduce(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """x = n pi/2 + (y0 + y1) with |y0| <= ~pi/4: (n mod 4, y0, y1), fdlibm's medium-range
    reduction (e_rem_pio2.c), n rounded half away from zero: one step with pi/2 in 33 + 53 bits,
    a second (and third) with the next 33 bits where the first cancelled more than 16 (the
    second more than 49) bits. A step's r = t - n p is exact only where it cancels, so a later
    step is taken only there."""
    finite = np.isfinite(x)
    if np.any(np.abs(x[finite]) >= SIN_COS_LIMIT):
        raise ValueError(f"strict_math: sin/cos argument {float(np.max(np.abs(x[finite])))!r} rad is beyond "
                         f"{SIN_COS_LIMIT:.0f}, where the reduction by pi/2 loses bits")
    n = np.copysign(np.floor(np.abs(x) * INV_PIO2 + 0.5), x)  # NaN for a non-finite x, whose sine is NaN
    r = x - n * PIO2_1
    w = n * PIO2_1T
    y0 = r - w
    cancelled = _exponent(x) - _exponent(y0) > 16
    if cancelled.any():
        r[cancelled], w[cancelled], y0[cancelled] = _further_steps(x[cancelled], n[cancelled], r[cancelled])
    return np.mod(np.where(finite, n, 0.0), 4.0).astype(np.int64), y0, (r - y0) - w


def _further_steps(x: np.ndarray, n: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(r, w, y0) of the second reduction step, or of the third where the second cancels more than
    49 bits (e_rem_pio2.c)."""
    steps = []
    for part, tail in ((PIO2_2, PIO2_2T), (PIO2_3, PIO2_3T)):
        t = r
        w = n * part
        r = t - w
        w = n * tail - ((t - r) - w)
        steps.append((r, w, r - w))
    second = _exponent(x) - _exponent(steps[0][2]) <= 49
    return tuple(np.where(second, early, late) for early, late in zip(*steps))


def _exponent(x: np.ndarray) -> np.ndarray:
    """The biased binary exponent of each float64 (bits 52-62)."""
    return (_high_word(x) >> 20) & 0x7FF


def sin_cos(x: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """(sin x, cos x) of radians, |x| < 2^19 pi/2, from one reduction (fdlibm s_sin.c, s_cos.c)."""
    x = _array(x)
    shape, x = x.shape, x.reshape(-1)
    with np.errstate(invalid="ignore"):
        small = (_high_word(x) & 0x7FFFFFFF) <= 0x3FE921FB  # |x| <= pi/4: no reduction (fdlibm)
        quadrant, y0, y1 = _reduce(np.where(small, 0.0, x))
        y0, y1 = np.where(small, x, y0), np.where(small, 0.0, y1)
        quadrant = np.where(small, 0, quadrant)
        sine, cosine = _kernel_sin(y0, y1, ~small), _kernel_cos(y0, y1)
    odd = (quadrant & 1).astype(bool)
    # quadrants 0-3: sin is sine, cosine, -sine, -cosine; cos is cosine, -sine, -cosine, sine
    sin_x, cos_x = np.where(odd, cosine, sine), np.where(odd, sine, cosine)
    return (np.where(quadrant >= 2, -sin_x, sin_x).reshape(shape),
            np.where((quadrant == 1) | (quadrant == 2), -cos_x, cos_x).reshape(shape))


def sin(x: np.ndarray | float) -> np.ndarray:
    """Sine of radians, |x| < 2^19 pi/2."""
    return sin_cos(x)[0]


def cos(x: np.ndarray | float) -> np.ndarray:
    """Cosine of radians, |x| < 2^19 pi/2."""
    return sin_cos(x)[1]


def atan(x: np.ndarray | float) -> np.ndarray:
    """Arc tangent (rad, in [-pi/2, pi/2]); fdlibm s_atan.c: |x| reduced to [0, 7/16] about
    atan(0.5), atan(1), atan(1.5) or atan(inf), then an 11-term odd polynomial."""
    x = _array(x)
    a = np.abs(x)
    band = np.searchsorted(ATAN_BANDS, a, side="right")  # 0 (no reduction) .. 4 (about infinity)
    # fdlibm's reduced arguments a, (2a - 1)/(2 + a), (a - 1)/(a + 1), (a - 1.5)/(1 + 1.5a), -1/a as
    # (p a - q)/(r + s a): the multiplications by 0, 1 and 2 and the additions of 0 are exact
    p, q, r, s = ATAN_REDUCTION[:, band]
    with np.errstate(invalid="ignore"):
        reduced = np.where(np.isinf(a), -0.0, (p * a - q) / (r + s * a))
    z = reduced * reduced
    w = z * z
    odd, even = ATAN_COEFFICIENTS[0::2], ATAN_COEFFICIENTS[1::2]
    series = z * _horner(w, odd) + w * _horner(w, even)
    index = np.maximum(band - 1, 0)
    result = np.where(band == 0, reduced - reduced * series,
                      ATAN_HI[index] - ((reduced * series - ATAN_LO[index]) - reduced))
    return np.copysign(result, x)


def atan2(y: np.ndarray | float, x: np.ndarray | float) -> np.ndarray:
    """Angle (rad, in [-pi, pi]) of the point (x, y); fdlibm e_atan2.c: atan(|y/x|) moved to the
    quadrant by the signs, pi carried in two parts. atan2(+-0, +0) = +-0, atan2(+-0, -0) = +-pi."""
    y, x = np.broadcast_arrays(_array(y), _array(x))
    with np.errstate(divide="ignore", invalid="ignore"):
        z = atan(np.abs(y / x))
    z = np.where(y == 0.0, 0.0, z)
    result = np.where(np.signbit(x), PI - (z - PI_LO), z)
    result = np.where((x == 0.0) & (y != 0.0), PIO2_HI, result)
    return np.copysign(result, y)


def asin(x: np.ndarray | float) -> np.ndarray:
    """Arc sine (rad) of x in [-1, 1] (NaN outside); fdlibm e_asin.c: a rational approximation
    below 0.5, asin(x) = pi/2 - 2 asin(sqrt((1 - |x|)/2)) above, the square root split in two
    words between 0.5 and 0.975."""
    x = _array(x)
    a = np.abs(x)
    t_small = x * x
    small = x + x * (_rational(t_small))
    w = 1.0 - a
    t = w * 0.5
    with np.errstate(invalid="ignore"):
        s = np.sqrt(t)
    ratio = _rational(t)
    steep = PIO2_HI - (2.0 * (s + s * ratio) - PIO2_LO)
    s_high = _with_words(_high_word(s), np.zeros(s.shape, dtype=np.uint64))
    with np.errstate(divide="ignore", invalid="ignore"):  # s = 0 at |x| = 1, taken from the line below
        c = (t - s_high * s_high) / (s + s_high)
    p = 2.0 * s * ratio - (PIO2_LO - 2.0 * c)
    moderate = PIO4_HI - (p - (PIO4_HI - 2.0 * s_high))
    large = np.copysign(np.where((_high_word(a) & 0x7FFFFFFF) >= 0x3FEF3333, steep, moderate), x)  # |x| >= 0.975
    result = np.where(a < 0.5, small, large)
    result = np.where(a == 1.0, x * PIO2_HI + x * PIO2_LO, result)
    return np.where(a > 1.0, np.nan, result)


def _rational(t: np.ndarray) -> np.ndarray:
    """fdlibm asin's p(t)/q(t), t = x^2 or (1 - |x|)/2."""
    return t * _horner(t, ASIN_P) / (1.0 + t * _horner(t, ASIN_Q))


def exp(x: np.ndarray | float) -> np.ndarray:
    """e^x for x in [-708, 709]; fdlibm e_exp.c: x = k ln2 + r, |r| <= ln2/2, a rational
    approximation of e^r, scaled by 2^k exactly."""
    x = _array(x)
    if np.any((x < EXP_RANGE[0]) | (x > EXP_RANGE[1])):
        raise ValueError(f"strict_math: exp argument outside {list(EXP_RANGE)}")
    k = np.where((_high_word(x) & 0x7FFFFFFF) > 0x3FD62E42, np.trunc(INV_LN2 * x + np.copysign(0.5, x)), 0.0)
    high = x - k * LN2_HI
    low = k * LN2_LO
    r = high - low
    t = r * r
    c = r - t * _horner(t, EXP_COEFFICIENTS)
    y = 1.0 - ((low - (r * c) / (2.0 - c)) - high)
    return np.ldexp(y, k.astype(np.int64))


def log(x: np.ndarray | float) -> np.ndarray:
    """Natural logarithm of positive x; fdlibm e_log.c: x = 2^k (1 + f), sqrt(2)/2 <= 1 + f <
    sqrt(2), log(1 + f) = 2s + 2s^3/3 + ... with s = f/(2 + f)."""
    x = _array(x)
    subnormal = (x > 0.0) & (x < np.finfo(np.float64).tiny)
    scaled = np.where(x > 0.0, x, 1.0) * np.where(subnormal, 2.0 ** 54, 1.0)
    high = _high_word(scaled)
    k = (high >> 20) - 1023 - np.where(subnormal, 54, 0)
    mantissa = high & 0x000FFFFF
    half = (mantissa + 0x95F64) & 0x100000  # 1 + f, or (1 + f)/2 when the mantissa is above sqrt(2)
    normalised = _with_words(mantissa | (half ^ 0x3FF00000), scaled.view(np.uint64))
    k = (k + (half >> 20)).astype(np.float64)
    f = normalised - 1.0
    s = f / (2.0 + f)
    z = s * s
    w = z * z
    r = z * _horner(w, LOG_COEFFICIENTS[0::2]) + w * _horner(w, LOG_COEFFICIENTS[1::2])
    half_square = 0.5 * f * f
    wide = ((mantissa - 0x6147A) | (0x6B851 - mantissa)) > 0
    result = np.where(wide, k * LN2_HI - ((half_square - (s * (half_square + r) + k * LN2_LO)) - f),
                      k * LN2_HI - ((s * (f - r) - k * LN2_LO) - f))
    result = np.where(x == 0.0, -np.inf, result)
    result = np.where(np.isposinf(x), np.inf, result)
    return np.where((x < 0.0) | np.isnan(x), np.nan, result)


def log10(x: np.ndarray | float) -> np.ndarray:
    """Common logarithm of positive x: log(x) / ln 10 (about 2 ulp)."""
    return log(x) * INV_LN10


def power(x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
    """x^y for positive x: exp(y log x) (relative error about |y ln x| 2^-53)."""
    return exp(_array(y) * log(x))


def hypot(x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
    """sqrt(x^2 + y^2) (within 1 ulp; no guard against overflow, for lengths in metres)."""
    x, y = _array(x), _array(y)
    return np.sqrt(x * x + y * y)


def norm(vectors: np.ndarray, axis: int = -1, keepdims: bool = False) -> np.ndarray:
    """Euclidean length along `axis`, summed in a fixed order: `np.linalg.norm` of one vector
    calls BLAS's dot, whose kernel (and so its rounding) OpenBLAS picks by processor."""
    vectors = _array(vectors)
    return np.sqrt(np.add.reduce(vectors * vectors, axis=axis, keepdims=keepdims))
