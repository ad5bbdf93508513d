"""A long table held as numpy columns: what a :class:`~cdgps_cli.core.records.Run` carries.

The estimators read a run's phase, gyro and actuator tables column by column and map names to
config indices; they need no pandas, and ``cdgps init`` / ``cdgps estimate`` do not import it
(issue 13 item 5: importing pandas alone was a third of the time outside the filter).  A name
column is held as integer codes into its sorted names (as a categorical column is), so a
million rows of a few antenna names cost 4 MB.  :meth:`Table.frame` gives the pandas view for
analysis and tests; :meth:`Table.from_frame` takes one in.
"""

from __future__ import annotations

from typing import Iterable, Mapping, Sequence

import numpy as np


class Deferred:
    """A column computed on first use: ``make()`` returns what the column would have been given as
    (an array for a number column, the codes for a name column).  A run's reader defers the columns
    ``cdgps estimate`` does not read (receiver, master, C/N₀: a quarter of the RUN's decoding)."""

    def __init__(self, make):
        self.make = make


def _name_order(words: list[str]) -> np.ndarray | None:
    """Codes into ``words`` → codes into ``sorted(words)``: the lookup table, None when already sorted."""
    if all(a < b for a, b in zip(words, words[1:])):
        return None
    order = sorted(range(len(words)), key=words.__getitem__)
    new_code = np.empty(len(words), dtype=np.int32)
    new_code[order] = np.arange(len(words), dtype=np.int32)
    return new_code


def _renumbered(codes: np.ndarray, lut: np.ndarray | None) -> np.ndarray:
    valid = codes.size == 0 or lut is None or (0 <= int(codes.min()) and int(codes.max()) < lut.size)
    return codes if lut is None or not valid else lut[codes]


class Table:
    """A long table as numpy columns, number columns and name columns.

    Parameters
    ----------
    numbers : mapping of str to ndarray (R,)
        Number columns (float or integer), each of R rows.
    names : mapping of str to (ndarray (R,) of int, sequence of str)
        Name columns as ``(codes, words)``: row r's name is ``words[codes[r]]``; codes are
        integers with ``0 ≤ code < len(words)``; the words are distinct.  The table keeps the
        words sorted (codes renumbered), so code order is name order.
    order : sequence of str, optional
        Column order (default: the number columns, then the name columns).
    categorical : iterable of str, optional
        Name columns that :meth:`frame` gives as pandas categoricals (the others as object
        columns of str).

    A number column's array, or a name column's codes, may be a :class:`Deferred`: computed on
    first use and then checked like the others (at least one column must be given as an array).

    Raises
    ------
    ValueError
        Columns of different lengths, codes outside their words, repeated words, an unknown or
        missing column in ``order`` (for a deferred column: when it is computed).
    """

    def __init__(self, numbers: Mapping[str, np.ndarray], names: Mapping[str, tuple] | None = None,
                 order: Sequence[str] | None = None, categorical: Iterable[str] = ()):
        self._numbers = {k: v if isinstance(v, Deferred) else np.asarray(v) for k, v in numbers.items()}
        self._codes: dict = {}
        self._words: dict[str, tuple[str, ...]] = {}
        self._lut: dict[str, np.ndarray | None] = {}
        for k, (codes, words) in (names or {}).items():
            words = [str(w) for w in words]
            self._words[k] = tuple(sorted(words))
            self._lut[k] = _name_order(words)
            self._codes[k] = codes if isinstance(codes, Deferred) else \
                _renumbered(np.asarray(codes, dtype=np.int32), self._lut[k])
        self._order = list(order) if order is not None else [*self._numbers, *self._codes]
        self._categorical = frozenset(categorical)
        self._check()

    def _check(self) -> None:
        every = {**self._numbers, **self._codes}
        if sorted(self._order) != sorted(every) or len(set(self._order)) != len(self._order):
            raise ValueError(f"table columns {sorted(every)}: order {self._order} does not list each once")
        present = {k: v for k, v in every.items() if not isinstance(v, Deferred)}
        if every and not present:
            raise ValueError("table columns: every column deferred (give at least one as an array)")
        lengths = {k: v.shape for k, v in present.items()}
        if len(set(lengths.values())) > 1 or any(len(s) != 1 for s in lengths.values()):
            raise ValueError(f"table columns of different lengths or not 1-D: {lengths}")
        for k, words in self._words.items():
            if len(set(words)) != len(words):
                raise ValueError(f"name column {k!r}: repeated names in {list(words)}")
            if not isinstance(self._codes[k], Deferred):
                self._check_codes(k, self._codes[k])
        unknown = self._categorical - set(self._codes)
        if unknown:
            raise ValueError(f"categorical columns {sorted(unknown)} are not name columns")

    def _check_codes(self, k: str, codes: np.ndarray) -> None:
        if codes.size and (int(codes.min()) < 0 or int(codes.max()) >= len(self._words[k])):
            raise ValueError(f"name column {k!r}: codes outside its {len(self._words[k])} names")

    def _number(self, k: str) -> np.ndarray:
        v = self._numbers[k]
        if isinstance(v, Deferred):
            v = np.asarray(v.make())
            if v.shape != (len(self),):
                raise ValueError(f"table column {k!r}: {list(v.shape)} values for {len(self)} rows")
            self._numbers[k] = v
        return v

    def _code(self, k: str) -> np.ndarray:
        c = self._codes[k]
        if isinstance(c, Deferred):
            c = np.asarray(c.make(), dtype=np.int32)
            if c.shape != (len(self),):
                raise ValueError(f"name column {k!r}: {list(c.shape)} codes for {len(self)} rows")
            self._check_codes(k, c)
            c = self._codes[k] = _renumbered(c, self._lut[k])
        return c

    # ------------------------------------------------------------------------------------------
    # reading

    def __len__(self) -> int:
        first = next((v for v in [*self._numbers.values(), *self._codes.values()] if not isinstance(v, Deferred)), None)
        return 0 if first is None else int(first.shape[0])

    @property
    def columns(self) -> list[str]:
        """Column names, in order."""
        return list(self._order)

    def __contains__(self, column: str) -> bool:
        return column in self._numbers or column in self._codes

    def __getitem__(self, column: str) -> np.ndarray:
        """Column as numpy (R,): numbers as stored, names as an object array of str."""
        if column in self._numbers:
            return self._number(column)
        if column in self._codes:
            return np.asarray(self._words[column] or [""], dtype=object)[self._code(column)]
        raise KeyError(f"table has no column {column!r} (columns: {', '.join(self._order)})")

    def codes(self, column: str) -> tuple[np.ndarray, tuple[str, ...]]:
        """A name column as ``(codes (R,) int32, words)``: row r is ``words[codes[r]]``."""
        if column not in self._codes:
            raise KeyError(f"table has no name column {column!r} (name columns: {', '.join(self._codes)})")
        return self._code(column), self._words[column]

    def index_in(self, column: str, vocabulary: Sequence[str], rows=None) -> np.ndarray:
        """Each row's position of its name in ``vocabulary``, (R,) int64; −1 where it is absent.
        ``rows`` (a mask or indices): those rows only."""
        codes, words = self.codes(column)
        where = {w: i for i, w in enumerate(vocabulary)}
        lut = np.array([where.get(w, -1) for w in words] or [-1], dtype=np.int64)
        return lut[codes if rows is None else codes[rows]]

    def names_not_in(self, column: str, vocabulary: Sequence[str], rows=None) -> list[str]:
        """The names of a column that occur in some row (of ``rows``) and are not in ``vocabulary``
        (sorted)."""
        codes, words = self.codes(column)
        codes = codes if rows is None else codes[rows]
        used = np.flatnonzero(np.bincount(codes, minlength=len(words))) if codes.size else []
        known = set(vocabulary)
        return sorted(words[i] for i in used if words[i] not in known)

    def take(self, rows: np.ndarray) -> Table:
        """The rows selected by a boolean mask or an index array (names and order kept; a deferred
        column stays deferred)."""
        def sub(get, k, v):
            return Deferred(lambda: get(k)[rows]) if isinstance(v, Deferred) else v[rows]

        return Table({k: sub(self._number, k, v) for k, v in self._numbers.items()},
                     {k: (sub(self._code, k, c), self._words[k]) for k, c in self._codes.items()},
                     self._order, self._categorical)

    # ------------------------------------------------------------------------------------------
    # pandas

    def frame(self):
        """The table as a pandas DataFrame (a new one each call; pandas is imported here).

        Name columns listed as categorical become ``pd.Categorical`` over the sorted words, the
        others object columns of str; an empty name column is an empty float column."""
        import pandas as pd  # noqa: PLC0415 (the estimators never need it)

        out = {}
        for k in self._order:
            if k in self._numbers:
                out[k] = self._number(k)
            elif not len(self):
                out[k] = np.array([], dtype=float)
            elif k in self._categorical:
                out[k] = pd.Categorical.from_codes(self._code(k), categories=list(self._words[k]))
            else:
                out[k] = self[k]
        return pd.DataFrame(out, columns=self._order)

    @classmethod
    def from_frame(cls, df, name_columns: Iterable[str] | None = None,
                   categorical: Iterable[str] | None = None) -> Table:
        """A Table from a pandas DataFrame.

        Parameters
        ----------
        df : DataFrame
            Any index (rows are taken in order).
        name_columns : iterable of str, optional
            Columns held as names (default: the categorical, object and string columns).
        categorical : iterable of str, optional
            Name columns that :meth:`frame` gives as categoricals (default: those that are).

        Raises
        ------
        ValueError
            A name column with a missing value.
        """
        import pandas as pd  # noqa: PLC0415

        if name_columns is None:
            name_columns = [c for c in df.columns
                            if isinstance(df[c].dtype, pd.CategoricalDtype) or df[c].dtype == object
                            or pd.api.types.is_string_dtype(df[c].dtype)]
        name_columns = set(name_columns)
        categorical_given = None if categorical is None else list(categorical)
        numbers, names, categorical = {}, {}, categorical_given or []
        for c in df.columns:
            col = df[c]
            if c not in name_columns:
                numbers[c] = col.to_numpy()
                continue
            if isinstance(col.dtype, pd.CategoricalDtype):
                if categorical_given is None:
                    categorical.append(c)
                codes, uniq = col.cat.codes.to_numpy(), col.cat.categories
            else:
                codes, uniq = pd.factorize(col, sort=True)
            if (codes < 0).any():
                raise ValueError(f"name column {c!r}: missing names in rows {np.flatnonzero(codes < 0)[:5].tolist()}")
            names[c] = (codes, [str(u) for u in uniq])
        return cls(numbers, names, [str(c) for c in df.columns], categorical)

    def __repr__(self) -> str:
        return f"Table({len(self)} rows; columns {', '.join(self._order)})"
