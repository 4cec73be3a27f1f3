"""Thesis-compatible ``.m`` export of an identification run.

The thesis' evaluation scripts read MATLAB matrices ``data_exc_dx`` ...
``data_exc_z``, one row per frequency step of the axis excited, with the
column layout `THESIS_COLUMNS` (1-based as in MATLAB).  The thesis' appendix
fixes only columns 1, 3, 5, 7 and 9, so a second layout is just as faithful
and is read as well: a radial matrix of the 18 columns `RADIAL_COLUMNS` (the
radial bearings' channels only) and a Z matrix of the 6 columns
`AXIAL_COLUMNS`; the layout of each matrix is told by its width.  Columns
3-10 are the thesis' own layout, so its appendix formula
``data_exc_dx(:,7)./data_exc_dx(:,3)/1e6`` gives the DX plant in m/A; positions
are therefore written in micrometres.  Numbers are written with 17 significant
digits by default, so every double round-trips exactly through the text.  The file is
data for a strict parser, never to be evaluated: `parse_thesis_m` accepts only
``data_exc_<axis> = [numbers]`` assignments and comments, with a hand-written
linear-time scanner, and `read_thesis_m` turns such a file back into an
identification log.
"""

import math
import os
from string import ascii_letters
from typing import NamedTuple

import numpy as np

from .errors import LogError
from .io import atomic_path
from .logs import CHANNELS, identification_frame, validate_identification_log
from .machine import ALL_AXES, RADIAL_AXES

__all__ = [
    "THESIS_COLUMNS",
    "RADIAL_COLUMNS",
    "AXIAL_COLUMNS",
    "thesis_log",
    "write_thesis_m",
    "variable_name",
    "MFileParseError",
    "parse_thesis_m",
    "read_thesis_m",
]

_POSITION_SCALE = 1e6  # m -> um, as in the thesis

#: (channel, scale) of columns 3-18 of the radial-only layout and 3-6 of the axial-only layout.
_RADIAL_LAYOUT = (
    tuple((f"U2_{axis}", 1.0) for axis in RADIAL_AXES)
    + tuple((f"V2_{axis}", _POSITION_SCALE) for axis in RADIAL_AXES)
    + tuple((f"I_{side}_{axis}", 1.0) for axis in RADIAL_AXES for side in ("upper", "lower"))
)
_AXIAL_LAYOUT = (("U2_Z", 1.0), ("V2_Z", _POSITION_SCALE), ("I_upper_Z", 1.0), ("I_lower_Z", 1.0))
#: (channel, scale) of columns 3-22 of the full layout; columns 1 and 2 are frequency and amplitude.
_LAYOUT = _RADIAL_LAYOUT + _AXIAL_LAYOUT
#: width -> layout (the radial-only and axial-only widths differ, so a matrix's width tells its layout)
_LAYOUTS = {2 + len(layout): layout for layout in (_LAYOUT, _RADIAL_LAYOUT, _AXIAL_LAYOUT)}


def _describe(layout):
    return ("frequency [Hz]", "amplitude [A]") + tuple(f"{channel} [{'um' if scale != 1.0 else 'A'}]" for channel, scale in layout)


#: Description of the 22 columns, in order (MATLAB column = index + 1).
THESIS_COLUMNS = _describe(_LAYOUT)
#: The 18 columns of a radial axis' matrix in the radial-only layout, and the 6 of the Z matrix in the axial-only one.
RADIAL_COLUMNS = _describe(_RADIAL_LAYOUT)
AXIAL_COLUMNS = _describe(_AXIAL_LAYOUT)


def variable_name(axis):
    """MATLAB variable holding the steps of an excited axis: ``"DX"`` -> ``"data_exc_dx"``."""
    return f"data_exc_{axis.lower()}"


def _real(value, digits=17):
    return f"{value:.{digits}g}"


def _complex(value, digits=17):
    return f"{value.real:.{digits}g}{value.imag:+.{digits}g}i"


def _axis_rows(frame, axis, digits):
    """Lines of the matrix of one excited axis, by increasing step (22 columns, or 18 / 6 for a partial log)."""
    part = frame[frame["excited_axis"] == axis]
    table = part.pivot(index="step", columns="channel", values=["re", "im"]).sort_index()
    per_step = part.groupby("step")[["frequency_hz", "amplitude_a"]].first().sort_index()
    present = set(part["channel"])
    layout = _LAYOUT if all(c in present for c, _ in _LAYOUT) else _AXIAL_LAYOUT if axis == "Z" else _RADIAL_LAYOUT
    channels = [channel for channel, _ in layout]
    scale = np.array([scale for _, scale in layout])
    coefficients = (table["re"][channels].to_numpy() + 1j * table["im"][channels].to_numpy()) * scale
    lines = []
    for (frequency_hz, amplitude_a), row in zip(per_step.to_numpy(), coefficients):
        values = [_real(frequency_hz), _real(amplitude_a, digits)] + [_complex(value, digits) for value in row]
        lines.append("  ".join(values) + ";")
    return lines


def write_thesis_m(frame, path, header_lines=(), digits=17):
    """Write an identification log as a MATLAB script in the thesis' format.

    Parameters
    ----------
    frame : pandas.DataFrame
        Identification log (`ambid.logs.identification_frame`), SI units; it is
        validated first.
    path : str or Path
        Target ``.m`` file, written atomically.
    header_lines : sequence of str, optional
        Comment lines (machine, run, ...) placed at the top, each prefixed ``% ``.
    digits : int, optional
        Significant digits of amplitudes and coefficients (frequencies keep 17).
        17, the default, round-trips every double exactly; fewer make a smaller
        file for data whose noise is far above that precision.

    Notes
    -----
    For each axis present in ``frame`` (in `ALL_AXES` order) the file assigns
    ``data_exc_<axis> = [`` ... ``];`` with one row per step: frequency [Hz]
    and amplitude [A] as reals, then the 20 channel coefficients as complex
    literals ``re+imi`` in the `THESIS_COLUMNS` layout, positions in µm.  A
    log whose steps carry only their own bearing's channels is written in the
    18-column `RADIAL_COLUMNS` and 6-column `AXIAL_COLUMNS` layout instead.
    Repeated steps (``level`` > 0) are not written: the thesis format holds one
    row per frequency step.

    Raises
    ------
    LogError
        If ``frame`` is not a valid identification log; nothing is written then.
    """
    validate_identification_log(frame, str(path))
    if "level" in frame.columns:  # the thesis format has one row per step: repeats at other amplitudes stay in the Parquet log
        frame = frame[frame["level"] == 0]

    def columns(names):
        return ", ".join(f"{column} {description}" for column, description in enumerate(names, start=1))

    lines = [f"% {text}" for header in header_lines for text in str(header).splitlines() or [""]]
    full = all(set(CHANNELS) <= set(part["channel"]) for _, part in frame.groupby("excited_axis"))
    if full:
        lines.append(f"% columns: {columns(THESIS_COLUMNS)}")
    else:
        lines.append(f"% columns of data_exc_dx, _dy, _nx, _ny (radial bearings only): {columns(RADIAL_COLUMNS)}")
        lines.append(f"% columns of data_exc_z (axial bearing only): {columns(AXIAL_COLUMNS)}")
    present = set(frame["excited_axis"])
    for axis in (axis for axis in ALL_AXES if axis in present):
        lines += ["", f"{variable_name(axis)} = ["] + _axis_rows(frame, axis, digits) + ["];"]
    with atomic_path(path) as temporary:
        temporary.write_text("\n".join(lines) + "\n", encoding="utf-8")


# ---------------------------------------------------------------------------- reading
class MFileParseError(LogError):
    """A thesis-style ``.m`` file that is not plain data in the accepted grammar.

    Parameters
    ----------
    path : str
        The file (or ``"<string>"``), also available as ``source``.
    line, column : int
        1-based position of the offending character; columns count characters
        (code points), a tab counting as one.
    message : str
        What is wrong there.

    Notes
    -----
    ``str(error)`` is ``"{path}:{line}:{column}: {message}"``, the format of
    compilers and editors, so the position can be jumped to.
    """

    def __init__(self, path, line, column, message):
        super().__init__(f"{path}:{line}:{column}", message)
        self.source = self.path = path
        self.line = line
        self.column = column

    def __reduce__(self):
        return type(self), (self.path, self.line, self.column, self.message)


_DIGITS = frozenset("0123456789")
_NAME_START = frozenset(ascii_letters)
_NAME_CHARS = _NAME_START | _DIGITS | {"_"}
_BLANKS = frozenset(" \t")
_PUNCTUATION = frozenset("=[];,")
_AFTER_NUMBER = frozenset(" \t,;]%\n")  # plus "\r\n", "..." and the end of the text
_NON_FINITE = frozenset({"inf", "nan"})
_VARIABLES = {variable_name(axis): axis for axis in ALL_AXES}
_HINTS = {
    "'": "strings and transposes are not allowed",
    '"': "strings are not allowed",
    "(": "function calls and indexing are not allowed",
    ")": "function calls and indexing are not allowed",
    "{": "cell arrays are not allowed",
    "}": "cell arrays are not allowed",
    "\r": "lone carriage return; lines end with \\n or \\r\\n",
}
_ARITHMETIC = frozenset("*/\\^&|~<>!@:")
_COMPLEX_HINT = "a sign after a number only starts the imaginary part of a complex literal re±imi (no spaces)"
_GRAMMAR = "a thesis .m file holds only data_exc_<axis> = [numbers] assignments and % comments"


def _quote(text, limit=40):
    """``repr`` of ``text``, shortened to about ``limit`` characters (messages stay readable)."""
    return repr(text) if len(text) <= limit else repr(text[:limit]) + "..."


class _Token(NamedTuple):
    kind: str  # "name", "number", "newline", "eof" or one of "=[];,"
    value: object  # the name (str), the number (complex) or None
    line: int
    column: int


class _Scanner:
    """Linear-time tokenizer: every character is looked at a bounded number of times.

    Comments and ``...`` continuations (with the rest of their line) are
    skipped; a continuation also swallows its line end, so a row or a
    statement goes on on the next line.  Numbers are scanned whole, complex
    literals included, and must be followed by a separator.
    """

    def __init__(self, text, path):
        self.text = text
        self.path = path
        self.pos = 0
        self.line = 1
        self.line_start = 0

    def error(self, message, pos=None):
        """`MFileParseError` at ``pos`` (default: the current position) of the current line."""
        pos = self.pos if pos is None else pos
        return MFileParseError(self.path, self.line, pos - self.line_start + 1, message)

    def tokens(self):
        """Yield `_Token` s, ending with one ``"eof"``."""
        text, n = self.text, len(self.text)
        while self.pos < n:
            char = text[self.pos]
            if char in _BLANKS or (char == "\r" and text.startswith("\n", self.pos + 1)):
                self.pos += 1
            elif char == "\n":
                token = self._token("newline", None, 0)
                self._new_line(self.pos)
                yield token
            elif char == "%":
                self._skip_comment()
            elif text.startswith("...", self.pos):
                self._skip_continuation()
            elif char in _PUNCTUATION:
                yield self._token(char, None, 1)
            elif char in _DIGITS or char in "+-.":
                yield self._number()
            elif char in _NAME_START:
                start = self.pos
                name = self._name()
                yield _Token("name", name, self.line, start - self.line_start + 1)
            else:
                raise self.error(self._unexpected(char))
        yield self._token("eof", None, 0)

    # -- helpers ------------------------------------------------------------------------
    def _token(self, kind, value, width):
        token = _Token(kind, value, self.line, self.pos - self.line_start + 1)
        self.pos += width
        return token

    def _new_line(self, newline_pos):
        self.pos = newline_pos + 1
        self.line += 1
        self.line_start = self.pos

    def _end_of_line(self):
        end = self.text.find("\n", self.pos)
        return len(self.text) if end < 0 else end

    def _skip_comment(self):
        end = self._end_of_line()
        alone = not self.text[self.line_start : self.pos].strip(" \t")
        if alone and self.text[self.pos : end].rstrip(" \t\r") == "%{":
            raise self.error("block comments %{ ... %} are not supported; comment each line with %")
        self.pos = end

    def _skip_continuation(self):
        end = self._end_of_line()
        if end == len(self.text):
            self.pos = end
        else:
            self._new_line(end)

    def _skip(self, chars):
        text, pos = self.text, self.pos
        while pos < len(text) and text[pos] in chars:
            pos += 1
        self.pos = pos

    def _peek(self, offset=0):
        pos = self.pos + offset
        return self.text[pos] if pos < len(self.text) else ""

    def _name(self):
        start = self.pos
        self._skip(_NAME_CHARS)
        return self.text[start : self.pos]

    def _unexpected(self, char):
        if char in _ARITHMETIC:
            return f"unexpected {char!r}: arithmetic is not allowed, only numeric literals"
        hint = _HINTS.get(char, _GRAMMAR)
        return f"unexpected character {char!r}: {hint}"

    # -- numbers ------------------------------------------------------------------------
    def _number(self):
        """A real ``[+-]mantissa[e[+-]digits]``, an imaginary ``real i`` or a complex ``real±real i``."""
        start, line, column = self.pos, self.line, self.pos - self.line_start + 1
        self._check_sign()
        real_end = self._real()
        if self._peek() in ("i", "j"):
            value = complex(0.0, float(self.text[start:real_end]))
            self.pos += 1
        elif self._peek() in ("+", "-"):
            sign = self.pos
            self.pos += 1
            if not self._starts_number():
                raise self.error(f"arithmetic is not allowed: {_COMPLEX_HINT}", sign)
            imag_end = self._real()
            if self._peek() not in ("i", "j"):
                raise self.error(f"arithmetic is not allowed: {_COMPLEX_HINT}, or separate elements by a blank", sign)
            value = complex(float(self.text[start:sign]), float(self.text[sign:imag_end]))
            self.pos += 1
        else:
            value = complex(float(self.text[start:real_end]), 0.0)
        self._check_separator()
        if not (math.isfinite(value.real) and math.isfinite(value.imag)):
            message = f"number {_quote(self.text[start:self.pos])} overflows: non-finite data is not allowed"
            raise MFileParseError(self.path, line, column, message)
        return _Token("number", value, line, column)

    def _starts_number(self, offset=0):
        """Whether an unsigned mantissa starts at ``offset``: a digit, or ``.`` then a digit."""
        char = self._peek(offset)
        return char in _DIGITS or (char == "." and self._peek(offset + 1) in _DIGITS)

    def _check_sign(self):
        """A leading sign must be glued to its number: ``-1`` is data, ``- 1`` is arithmetic."""
        if self._peek() not in ("+", "-") or self._starts_number(1):
            return
        sign = self.pos
        if self._peek(1) in _NAME_START:
            self.pos += 1
            name = self._name()
            self.pos = sign
            if name.lower() in _NON_FINITE:
                raise self.error(f"non-finite value {_quote(self._peek() + name)} is not allowed")
        raise self.error(f"standalone {self._peek()!r}: arithmetic is not allowed, a sign must be glued to its number")

    def _real(self):
        """Scan ``[+-]digits[.digits][e[+-]digits]`` (either digit run may be empty, not both); return its end."""
        begin = self.pos
        if self._peek() in ("+", "-"):
            self.pos += 1
        start = self.pos
        self._skip(_DIGITS)
        digits = self.pos - start
        if self._peek() == "." and not self.text.startswith("...", self.pos):
            self.pos += 1
            fraction = self.pos
            self._skip(_DIGITS)
            digits += self.pos - fraction
        if not digits:
            raise self.error("malformed number: expected digits", begin)
        if self._peek() in ("e", "E"):
            exponent = self.pos
            self.pos += 1
            if self._peek() in ("+", "-"):
                self.pos += 1
            first_digit = self.pos
            self._skip(_DIGITS)
            if self.pos == first_digit:
                raise self.error("malformed number: the exponent has no digits", exponent)
        return self.pos

    def _check_separator(self):
        char = self._peek()
        if char == "" or char in _AFTER_NUMBER or self.text.startswith(("\r\n", "..."), self.pos):
            return
        if char in _ARITHMETIC or char in ("+", "-"):
            raise self.error(f"unexpected {char!r} after a number: arithmetic is not allowed")
        raise self.error(f"unexpected character {char!r} after a number: elements are separated by blanks or commas")


class _Matrix(NamedTuple):
    values: np.ndarray  # complex128, (rows, columns)
    line: int  # of the variable name
    column: int
    positions: list  # per row: [(line, column) of each element]


class _Parser:
    """Recursive-descent parser over `_Scanner` tokens (no recursion is needed: matrices do not nest)."""

    def __init__(self, text, path):
        self.path = path
        self.tokens = _Scanner(text, path).tokens()
        self.token = next(self.tokens)

    def error(self, message, token=None):
        token = token or self.token
        return MFileParseError(self.path, token.line, token.column, message)

    def advance(self):
        """Return the current token and scan the next one (never past the end)."""
        token = self.token
        if token.kind != "eof":
            self.token = next(self.tokens)
        return token

    def expect(self, kind, what):
        if self.token.kind != kind:
            raise self.error(f"expected {what}, found {self._describe(self.token)}")
        return self.advance()

    @staticmethod
    def _describe(token):
        if token.kind == "name":
            return f"name {_quote(token.value)}"
        if token.kind == "number":
            return "a number"
        if token.kind in ("newline", "eof"):
            return f"end of {'line' if token.kind == 'newline' else 'file'}"
        return repr(token.kind)

    def file(self):
        """file = { blank | comment | assignment }; return name -> `_Matrix` in file order."""
        matrices = {}
        while self.token.kind != "eof":
            if self.token.kind == "newline":
                self.advance()
            else:
                name, matrix = self.assignment(matrices)
                matrices[name] = matrix
        return matrices

    def assignment(self, seen):
        """assignment = NAME "=" matrix [";"] (end of line | end of file)."""
        token = self.token
        if token.kind != "name":
            raise self.error(f"expected an assignment data_exc_<axis> = [...], found {self._describe(token)}")
        if token.value not in _VARIABLES:
            known = ", ".join(_VARIABLES)
            raise self.error(f"only data_exc_* assignments are allowed ({known}), found {_quote(token.value)}")
        if token.value in seen:
            first = seen[token.value]
            raise self.error(f"{token.value} is assigned twice (first at line {first.line})")
        self.advance()
        self.expect("=", "'='")
        values, positions = self.matrix()
        if self.token.kind == ";":
            self.advance()
        if self.token.kind not in ("newline", "eof"):
            raise self.error(f"expected end of line after the assignment, found {self._describe(self.token)}")
        return token.value, _Matrix(values, token.line, token.column, positions)

    def matrix(self):
        """matrix = "[" rows "]"; return the (rows, columns) complex array and element positions."""
        opening = self.expect("[", "'[' (the value must be a literal matrix)")
        rows, row, comma = [], [], None
        while True:
            token = self.token
            if token.kind == "number":
                row.append(token)
                comma = None
            elif token.kind == ",":
                if not row or comma is not None:
                    raise self.error("empty element: ',' must stand between two elements", token)
                comma = token
            elif token.kind in (";", "newline", "]"):
                if comma is not None:
                    raise self.error("trailing ',': a row must not end with a comma", comma)
                self._end_row(rows, row)
                row = []
            else:
                raise self._bad_in_matrix(token, opening)
            self.advance()  # only now scan on: errors are reported in text order
            if token.kind == "]":
                return self._array(rows), [[(t.line, t.column) for t in r] for r in rows]

    def _end_row(self, rows, row):
        if not row:
            return  # empty rows (blank lines, ";;", a trailing ";") are ignored
        if rows and len(row) != len(rows[0]):
            first = rows[0][0]
            raise self.error(
                f"row has {len(row)} column(s), the first row (line {first.line}) has {len(rows[0])}", row[0]
            )
        rows.append(row)

    def _bad_in_matrix(self, token, opening):
        if token.kind == "eof":
            return self.error("unterminated matrix: this '[' is never closed", opening)
        if token.kind == "[":
            return self.error("nested brackets are not allowed", token)
        if token.kind == "name" and token.value.lower() in _NON_FINITE:
            return self.error(f"non-finite value {_quote(token.value)} is not allowed", token)
        if token.kind == "name":
            return self.error(f"names are not allowed inside a matrix, only numbers: found {_quote(token.value)}", token)
        return self.error(f"unexpected {self._describe(token)} inside a matrix", token)

    @staticmethod
    def _array(rows):
        if not rows:
            return np.zeros((0, 0), dtype=np.complex128)
        return np.array([[t.value for t in row] for row in rows], dtype=np.complex128)


def _parse(text, path):
    return _Parser(text, path).file()


def parse_thesis_m(text, path="<string>"):
    """Parse a thesis-style ``.m`` file as data, without evaluating anything.

    Parameters
    ----------
    text : str
        The file's content.
    path : str, optional
        Name quoted in errors.

    Returns
    -------
    dict of str to numpy.ndarray
        Variable name (``data_exc_dx`` ... ``data_exc_z``) -> complex128 array
        (rows, columns), in file order; ``[]`` gives a (0, 0) array.

    Raises
    ------
    MFileParseError
        At the first character outside the grammar, with its line and column.

    Notes
    -----
    The grammar (a strict subset of MATLAB)::

        file       = { blank line | comment | assignment }
        comment    = "%" ... end of line        (also after any token)
        assignment = NAME "=" "[" rows "]" [";"]  end of line
        rows       = row { (";" | newline) row }  (empty rows are ignored)
        row        = number { (blanks | [blanks] "," [blanks]) number }
        number     = real | real ("i"|"j") | real ("+"|"-") ureal ("i"|"j")
        real       = ["+"|"-"] ureal
        ureal      = (digits ["." [digits]] | "." digits) [("e"|"E") ["+"|"-"] digits]

    ``NAME`` is one of ``data_exc_dx``, ``_dy``, ``_nx``, ``_ny``, ``_z``, each
    assigned at most once; ``...`` continues a line (the rest of it is
    ignored).  As in MATLAB's matrix context a blank separates elements, so
    ``[1 -2]`` has two elements; a sign followed by a blank (``[1 - 2]``) is
    arithmetic and refused, as are names (``Inf``, ``NaN``, ``pi``), operators,
    strings, transposes, calls, nested brackets and ``%{`` block comments.
    Every row must have as many elements as the first.  Lines end with
    ``\n`` or ``\r\n``; blanks are spaces and tabs; the imaginary unit is a
    lowercase ``i`` or ``j`` glued to its number.  The scanner runs in
    time linear in ``len(text)`` and the parser does not recurse.
    """
    return {name: matrix.values for name, matrix in _parse(text, str(path)).items()}


#: Longest line accepted [bytes]: a thesis row of 22 complex columns at 17 digits is about 1,100 characters.
MAX_LINE_BYTES = 65536
#: Largest file accepted [bytes] (about 200,000 steps of the thesis layout).
MAX_FILE_BYTES = 256 * 2**20


def _read_text(path):
    """UTF-8 text of ``path`` (a leading byte-order mark is dropped), refusing oversized files and lines.

    The size is checked before reading and each line's length while reading in chunks, so an
    oversized file is refused after reading at most `MAX_LINE_BYTES` past its last line end.
    """
    try:
        with open(path, "rb") as handle:
            size = os.fstat(handle.fileno()).st_size
            if size > MAX_FILE_BYTES:
                raise LogError(str(path), f"{size} bytes: larger than the {MAX_FILE_BYTES} a thesis .m log may have")
            chunks, line, length = [], 1, 0  # length: bytes of the current line read so far
            while chunk := handle.read(MAX_LINE_BYTES):
                chunks.append(chunk)
                start = 0
                while True:
                    end = chunk.find(b"\n", start)
                    length += (end if end >= 0 else len(chunk)) - start
                    if length > MAX_LINE_BYTES:
                        raise MFileParseError(str(path), line, MAX_LINE_BYTES + 1,
                                              f"line longer than {MAX_LINE_BYTES} bytes: a thesis .m log holds one "
                                              "frequency step per line (rows end with ';' or a line break)")
                    if end < 0:
                        break
                    line, length, start = line + 1, 0, end + 1
            data = b"".join(chunks)
    except OSError as error:
        raise LogError(str(path), f"cannot read the file ({error.strerror or error})") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as error:
        line_start = data.rfind(b"\n", 0, error.start) + 1
        column = len(data[line_start : error.start].decode("utf-8", errors="replace")) + 1
        line = data.count(b"\n", 0, error.start) + 1
        raise MFileParseError(str(path), line, column, f"not UTF-8 text ({error.reason})") from None
    return text.removeprefix("\ufeff")


def _layout_of(name, values, path, position):
    """The layout of one matrix from its width; frequency and amplitude must be real."""
    axis = _VARIABLES[name]
    widths = (len(THESIS_COLUMNS), len(AXIAL_COLUMNS) if axis == "Z" else len(RADIAL_COLUMNS))
    if values.shape[1] not in widths:
        own = "the axial-only layout has 6 (Z's channels)" if axis == "Z" else "the radial-only layout has 18 (the radial bearings' channels)"
        message = f"{name} has {values.shape[1]} columns; the thesis layout has 22 (all channels), {own}"
        raise _matrix_error(path, position, 0, 0, message)
    complex_rows, complex_columns = np.nonzero(values[:, :2].imag)
    if complex_rows.size:
        row, col = int(complex_rows[0]), int(complex_columns[0])
        message = f"{name} row {row + 1}: column {col + 1} ({THESIS_COLUMNS[col]}) must be real, found {values[row, col]}"
        raise _matrix_error(path, position, row, col, message)
    return _LAYOUTS[values.shape[1]]


def _matrix_error(path, position, row, col, message):
    """`MFileParseError` at the element's line and column when known (a ``.m``), else a `LogError` (a ``.mat``)."""
    if position is None:
        return LogError(path, message)
    line, column = position(row, col)
    return MFileParseError(path, line, column, message)


def _step_records(axis, values, layout):
    """`identification_frame` records of one axis' thesis matrix, back to SI units."""
    channels = [channel for channel, _ in layout]
    scale = np.array([scale for _, scale in layout])
    records = []
    for step, row in enumerate(values):
        coefficients = np.zeros(len(channels), dtype=np.complex128)
        coefficients.real = row[2:].real / scale  # parts divided separately, each correctly rounded
        coefficients.imag = row[2:].imag / scale
        records.append(
            {
                "excited_axis": axis,
                "step": step,
                "frequency_hz": float(row[0].real),
                "amplitude_a": float(row[1].real),
                "attempts": 1,
                "channels": channels,
                "coefficients": coefficients,
                "noise_std": np.zeros(len(channels)),
            }
        )
    return records


def _without_padding(name, values, layout, notes):
    """A full-width matrix whose other bearing's columns are exactly 0 on every step: those columns are padding."""
    if layout is not _LAYOUT:
        return values, layout
    axis = _VARIABLES[name]
    own = _AXIAL_LAYOUT if axis == "Z" else _RADIAL_LAYOUT
    other = [2 + k for k, (channel, _) in enumerate(_LAYOUT) if (channel, _) not in own]
    if values.shape[0] and not np.any(values[:, other]):
        notes.append(f"{name}: the other bearing's {len(other)} columns are 0 on every step (padding): left out")
        keep = [0, 1] + [2 + k for k, entry in enumerate(_LAYOUT) if entry in own]
        return values[:, keep], own
    return values, layout


def thesis_log(matrices, path, positions=None, notes=None):
    """The identification log of thesis matrices ``data_exc_<axis>`` (from a ``.m`` or a ``.mat`` file).

    Parameters
    ----------
    matrices : dict of str to array (steps, columns)
        Variable name -> matrix, in the full layout (`THESIS_COLUMNS`) or the
        radial-only / axial-only one (`RADIAL_COLUMNS`, `AXIAL_COLUMNS`),
        told apart by width.  Empty matrices mean no steps of that axis.
    path : str
        The file, named in errors.
    positions : dict, optional
        Variable name -> callable ``(row, column) -> (line, column)`` of an
        element in the text, for errors at file:line:column.
    notes : list, optional
        Receives one line per conversion decision (padding left out).

    Returns
    -------
    pandas.DataFrame
        The validated identification log, SI units.
    """
    notes = [] if notes is None else notes
    records = []
    for name, values in matrices.items():
        if values.size == 0:
            continue
        layout = _layout_of(name, values, path, (positions or {}).get(name))
        values, layout = _without_padding(name, values, layout, notes)
        records += _step_records(_VARIABLES[name], values, layout)
    if not records:
        raise LogError(path, "no data: the file assigns no non-empty data_exc_* matrix")
    frame = identification_frame(records)
    validate_identification_log(frame, path)
    return frame


def read_thesis_m(path, notes=None):
    """Read a thesis-style ``.m`` file back into an identification log.

    Parameters
    ----------
    path : str or Path
        A file as written by `write_thesis_m` (or by hand in its grammar, see
        `parse_thesis_m`), UTF-8.
    notes : list, optional
        Receives a line per conversion decision (see Notes).

    Returns
    -------
    pandas.DataFrame
        The identification log (`ambid.logs.identification_frame` layout, SI
        units, positions back from µm to m), validated.

    Raises
    ------
    LogError
        If the file cannot be read, holds no data, or the log breaks the
        contract of `ambid.logs.validate_identification_log`.
    MFileParseError
        If the text is outside the grammar, a matrix does not have the 22
        `THESIS_COLUMNS` or its frequency or amplitude has an imaginary part;
        with line and column.

    Notes
    -----
    The thesis format carries less than the log: ``step`` is the 0-based row
    index within the axis' matrix (a log with gaps in its steps comes back
    renumbered), ``attempts`` is 1 and ``noise_std`` is 0.0 — the format has no
    noise estimate, and 0.0 (not NaN, which the log contract refuses) marks it
    absent.  An empty matrix ``[]`` means no steps for that axis.  A full-width
    matrix whose other bearing's columns are exactly 0 on every step was padded:
    those channels are left out (a line in ``notes``, when a list is given).
    ``frame.attrs["source_lines"]`` holds, per excited axis of a full-width
    (`THESIS_COLUMNS`) matrix, the line of each step (a list of each element's
    line for a row continued over lines), so that later checks can name the
    line and column of a value.
    """
    path = str(path)
    matrices = _parse(_read_text(path), path)

    def position(matrix):
        return lambda row, column: matrix.positions[row][column]

    frame = thesis_log({name: m.values for name, m in matrices.items()}, path,
                       {name: position(m) for name, m in matrices.items()}, notes)
    frame.attrs["source_lines"] = {
        _VARIABLES[name]: [row[0][0] if len({line for line, _ in row}) == 1 else [line for line, _ in row]
                           for row in matrix.positions]
        for name, matrix in matrices.items()
        if matrix.values.ndim == 2 and matrix.values.shape[1] == len(THESIS_COLUMNS) and matrix.values.shape[0] > 0
    }
    return frame
