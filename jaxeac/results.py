"""A grid run folder's per-seed results: one typed, compressed, columnar file, read back in one line.

``results.parquet`` holds one row per (algorithm, seed) of a grid run (SPEC G7):

| column | type | what |
|---|---|---|
| ``algo`` | dictionary string | the algorithm (`jaxeac.algorithm.ALGORITHMS`) |
| ``seed`` | int64 | seed i of ``fold_in(root_key, i)`` (R1) |
| ``successes`` | int32 | successful trials of T (the primary measure) |
| ``steps`` | int64 | agent-steps over all T trials |
| ``first_success`` | int32 | 1-based trial of the first success, −1 if none |
| ``finite`` | bool | the seed's p and V stayed finite (False: a numerical blow-up) |
| ``success_bits`` | fixed_size_binary[⌈T/8⌉] | success per trial; bit t (low bit first) is trial t |
| ``trial_steps`` | fixed_size_list<int16>[T] | chances used per trial (optional) |
| ``policy`` | fixed_size_list<int8>[S] | final greedy action per cell (optional) |

Written with zstd compression in row groups of `ROW_GROUP` seeds, so neither writing
nor reading needs more than a row group of temporaries. Load it with
``pandas.read_parquet`` / ``pyarrow.parquet.read_table``, or as numpy arrays with
`load_grid_results`; `unpack_success` turns ``success_bits`` into bool [N, T]
(``np.unpackbits(..., bitorder="little")``). Bits in a binary column write 20× faster
than a list of Arrow booleans, whose Parquet encoding costs a level per element.
Per-trial steps and policies take most of the bytes, so above
`FULL_OUTPUT_SEEDS` seeds they are left out unless asked for; ``per_seed.csv`` is
written beside it for runs of at most `CSV_SEEDS` seeds (or when asked for).

Run folders of earlier releases (``per_seed.csv``, ``curves.npz``, ``policies.npz``)
load through the same function.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from jaxeac.bits import SuccessBits, measures_of
from jaxeac.errors import UsageError

RESULTS_FILE = "results.parquet"
ROW_GROUP = 1 << 16  # seeds per row group: bounded temporaries when writing and reading
FULL_OUTPUT_SEEDS = 100_000  # above this many seeds, per-trial steps and policies only on request
CSV_SEEDS = 100_000  # per_seed.csv for runs of at most this many seeds (or on request)


@dataclasses.dataclass(frozen=True)
class OutputOptions:
    """What a grid run folder holds beyond the per-seed measures and success curves."""

    trial_steps: bool = True
    policies: bool = True
    per_seed_csv: bool = True

    @classmethod
    def auto(cls, n_seeds: int, *, full: bool | None = None, csv: bool | None = None) -> OutputOptions:
        """Everything for small runs; above `FULL_OUTPUT_SEEDS` / `CSV_SEEDS` seeds only the
        per-seed measures and success curves, unless `full` / `csv` say otherwise."""
        full = n_seeds <= FULL_OUTPUT_SEEDS if full is None else full
        return cls(trial_steps=full, policies=full, per_seed_csv=n_seeds <= CSV_SEEDS if csv is None else csv)


def _arrow():
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:  # pragma: no cover - a declared dependency
        raise UsageError("reading and writing results needs pyarrow; pip install pyarrow") from None
    return pa, pq


def _from_numpy(pa, values: np.ndarray):
    """The Arrow array of a 1-d NumPy array of numbers or booleans, built on its buffer:
    ``pa.array`` would first import pandas (0.75 s on the 2-core CPU, `python -X importtime`) to
    ask whether the values are pandas'."""
    values = np.ascontiguousarray(values)
    if values.dtype == bool:  # Arrow's booleans are bits, least significant first
        data = np.packbits(values, bitorder="little")
        return pa.Array.from_buffers(pa.bool_(), len(values), [None, pa.py_buffer(data)])
    return pa.Array.from_buffers(pa.from_numpy_dtype(values.dtype), len(values), [None, pa.py_buffer(values)])


def _strings(pa, items: list[str]):
    """The Arrow string array of `items`, built on its buffers (see `_from_numpy`)."""
    encoded = [item.encode() for item in items]
    offsets = np.cumsum([0, *map(len, encoded)], dtype=np.int32)
    return pa.Array.from_buffers(pa.string(), len(items),
                                 [None, pa.py_buffer(offsets), pa.py_buffer(b"".join(encoded))])


def _fixed_list(pa, values: np.ndarray, width: int):
    return pa.FixedSizeListArray.from_arrays(_from_numpy(pa, values.reshape(-1)), width)


def unpack_success(column, trials: int) -> np.ndarray:
    """bool [N, T] from a ``success_bits`` column (an Arrow array or chunked array)."""
    return success_bits(column, trials).unpack()


def schema(trials: int, n_states: int, options: OutputOptions):
    """The Arrow schema of ``results.parquet`` for T trials and S cells."""
    pa, _ = _arrow()
    fields = [
        pa.field("algo", pa.dictionary(pa.int8(), pa.string())), pa.field("seed", pa.int64()),
        pa.field("successes", pa.int32()), pa.field("steps", pa.int64()),
        pa.field("first_success", pa.int32()), pa.field("finite", pa.bool_()),
        pa.field("success_bits", pa.binary(-(-trials // 8))),
    ]
    if options.trial_steps:
        fields.append(pa.field("trial_steps", pa.list_(pa.int16(), trials)))
    if options.policies:
        fields.append(pa.field("policy", pa.list_(pa.int8(), n_states)))
    return pa.schema(fields, metadata={"jaxeac.format": "grid-results-1", "jaxeac.trials": str(trials)})


class ResultsWriter:
    """``results.parquet`` written as the run goes: algorithm by algorithm, a chunk of seeds at
    a time, in row groups of at most `ROW_GROUP` seeds (bounded memory whatever N).

    The caller writes into a staging folder (`jaxeac.io.staged_dir`), so a killed run
    leaves no half-written file in the run folder.
    """

    def __init__(self, path: str | Path, trials: int, n_states: int, options: OutputOptions):
        self.pa, pq = _arrow()
        self.options = options
        self.schema = schema(trials, n_states, options)
        # seeds and success bits are nearly all distinct: dictionary-encoding them only costs time
        # (2^20 rows written in 0.17 s instead of 0.23 s, a file 4 % smaller); the rows are the same
        plain = ("seed", "success_bits")
        self._writer = pq.ParquetWriter(str(path), self.schema, compression="zstd",
                                        use_dictionary=[f.name for f in self.schema if f.name not in plain])

    def write(self, algo: str, seeds: np.ndarray, measures: dict, trial_steps=None, policy=None) -> None:
        """Rows of `algo`: seeds [M], `measures_of`-style columns, per-trial steps [M, T] and
        policies [M, S] (needed when the options keep them)."""
        pa, opts = self.pa, self.options
        for start in range(0, len(seeds), ROW_GROUP):
            rows = slice(start, start + ROW_GROUP)
            bits = np.ascontiguousarray(measures["bits"][rows])
            n = bits.shape[0]
            algo_codes = _from_numpy(pa, np.zeros(n, np.int8))
            columns = {
                "algo": pa.DictionaryArray.from_arrays(algo_codes, _strings(pa, [algo])),
                "seed": _from_numpy(pa, np.asarray(seeds[rows], np.int64)),
                "successes": _from_numpy(pa, np.asarray(measures["successes"][rows], np.int32)),
                "steps": _from_numpy(pa, np.asarray(measures["steps_total"][rows], np.int64)),
                "first_success": _from_numpy(pa, np.asarray(measures["first_success"][rows], np.int32)),
                "finite": _from_numpy(pa, np.asarray(measures["finite"][rows], bool)),
                "success_bits": pa.FixedSizeBinaryArray.from_buffers(
                    pa.binary(bits.shape[1]), n, [None, pa.py_buffer(bits)]),
            }
            if opts.trial_steps:
                columns["trial_steps"] = _fixed_list(pa, np.asarray(trial_steps[rows], np.int16),
                                                     trial_steps.shape[1])
            if opts.policies:
                columns["policy"] = _fixed_list(pa, np.asarray(policy[rows], np.int8), policy.shape[1])
            batch = pa.record_batch([columns[f.name] for f in self.schema], schema=self.schema)
            self._writer.write_batch(batch, row_group_size=ROW_GROUP)

    def chunk_writer(self, algo: str, seeds: np.ndarray):
        """A `CompactCollector` ``on_chunk`` that writes each chunk of `algo`'s run (seeds [N])."""
        def on_chunk(start: int, chunk, measures: dict) -> None:
            rows = slice(start, start + measures["bits"].shape[0])
            self.write(algo, seeds[rows], measures,
                       trial_steps=np.abs(chunk.log) if self.options.trial_steps else None,
                       policy=chunk.policy)
        return on_chunk

    def close(self) -> None:
        self._writer.close()

    def __enter__(self) -> ResultsWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def write_grid_results(path: str | Path, results: dict, trials: int, n_states: int,
                       options: OutputOptions) -> None:
    """Write every algorithm's in-memory `SeedsResult` (seeds, success, steps, policy) to `path`,
    row group by row group (see `ResultsWriter`)."""
    with ResultsWriter(path, trials, n_states, options) as writer:
        for algo, r in results.items():
            for start in range(0, len(r.seeds), ROW_GROUP):
                rows = slice(start, start + ROW_GROUP)
                finite = None if getattr(r, "finite", None) is None else r.finite[rows]
                writer.write(algo, r.seeds[rows], measures_of(r.success[rows], r.steps[rows], finite),
                             trial_steps=r.steps[rows], policy=r.policy[rows])


@dataclasses.dataclass
class AlgoResults:
    """One algorithm's per-seed results read back from a run folder (numpy arrays)."""

    seeds: np.ndarray  # int64 [N]
    success: np.ndarray | SuccessBits  # bool [N, T] (SuccessBits when loaded `compact`)
    successes: np.ndarray  # int [N]
    first_success: np.ndarray  # int [N]
    steps_total: np.ndarray  # int [N]
    trial_steps: np.ndarray | None  # int [N, T], if the folder holds them
    policy: np.ndarray | None  # int [N, S], if the folder holds them
    finite: np.ndarray | None = None  # bool [N]: p and V stayed finite (None in older folders)


def _unpack_list(column, width: int, dtype) -> np.ndarray:
    """A fixed_size_list column as a numpy [rows, width] array."""
    import pyarrow as pa

    chunks = [c.flatten().to_numpy(zero_copy_only=False) for c in column.chunks] if column.num_chunks else []
    flat = np.concatenate(chunks) if chunks else np.empty(0, dtype)
    if isinstance(column.type, pa.FixedSizeListType) and column.type.list_size != width:
        raise ValueError(f"list width {column.type.list_size}, expected {width}")
    return flat.astype(dtype, copy=False).reshape(-1, width)


def success_bits(column, trials: int) -> SuccessBits:
    """`SuccessBits` [N, T] from a ``success_bits`` column (an Arrow array or chunked array)."""
    import pyarrow as pa

    width = -(-trials // 8)
    if isinstance(column, pa.ChunkedArray):
        column = column.combine_chunks()
    if column.type != pa.binary(width):
        raise ValueError(f"success_bits is {column.type}, expected fixed_size_binary[{width}]")
    raw = np.frombuffer(column.buffers()[1], np.uint8, count=len(column) * width,
                        offset=column.offset * width)
    return SuccessBits(raw.reshape(-1, width), trials)


def _rows_of(table, algo_codes: np.ndarray, code: int, pc, algo_column, algo: str):
    """The rows of one algorithm: a zero-copy slice when they are contiguous (as written)."""
    where = np.flatnonzero(algo_codes == code)
    if where.size and where[-1] - where[0] + 1 == where.size:
        return table.slice(int(where[0]), int(where.size))
    return table.filter(pc.equal(algo_column, algo))


#: The columns `compact` loading reads (no per-trial steps or policies).
COMPACT_COLUMNS = ("algo", "seed", "successes", "steps", "first_success", "finite", "success_bits")


def _load_parquet(path: Path, algos, trials: int, compact: bool = False) -> dict[str, AlgoResults]:
    pa, pq = _arrow()
    import pyarrow.compute as pc

    try:
        names = pq.read_schema(path).names
        with pq.ParquetFile(path) as file:  # (`pq.read_table` would import pandas, see `_from_numpy`)
            table = file.read(columns=[c for c in COMPACT_COLUMNS if c in names] if compact else None)
    except (pa.ArrowException, OSError) as exc:
        raise UsageError(f"{path} is not a readable results file ({str(exc).splitlines()[0]}); "
                         "re-run the experiment to rewrite it") from None
    needed = {"algo", "seed", "successes", "steps", "first_success", "success_bits"}
    missing = needed - set(table.column_names)
    if missing:
        raise UsageError(f"{path} lacks the column(s) {', '.join(sorted(missing))}; re-run the experiment")
    for name in ("seed", "successes", "steps", "first_success", "finite"):
        if name not in table.column_names:
            continue  # finite: absent in older folders
        column = table.column(name)
        kind = pa.types.is_boolean if name == "finite" else pa.types.is_integer
        if not kind(column.type) or column.null_count:
            what = f"has {column.null_count} missing value(s)" if kind(column.type) else f"is {column.type}"
            raise UsageError(f"{path}: column {name!r} {what}, not the "
                             f"{'booleans' if name == 'finite' else 'integers'} a run writes; re-run the "
                             "experiment")
    written = (table.schema.metadata or {}).get(b"jaxeac.trials")
    if written is not None and written != str(trials).encode():
        shown = written.decode(errors="replace")
        shown = shown if len(shown) <= 20 and shown.isprintable() else repr(shown[:20])
        raise UsageError(f"{path} holds runs of {shown} trials but summary.json says {trials}; "
                         "the files come from different runs: re-run the experiment")
    out = {}
    try:
        algo_column = table.column("algo").cast(pa.string())
        dictionary = pc.unique(algo_column).to_pylist()
        codes = pc.index_in(algo_column, value_set=_strings(pa, dictionary)).to_numpy(
            zero_copy_only=False)
        for algo in algos:
            if algo not in dictionary:
                raise UsageError(f"{path} has no rows for {algo!r}; the run folder is incomplete")
            rows = _rows_of(table, codes, dictionary.index(algo), pc, algo_column, algo)
            bits = success_bits(rows.column("success_bits"), trials)
            n_states = rows.schema.field("policy").type.list_size if "policy" in rows.column_names else 0
            out[algo] = AlgoResults(
                seeds=rows.column("seed").to_numpy(), success=bits if compact else bits.unpack(),
                successes=rows.column("successes").to_numpy(),
                first_success=rows.column("first_success").to_numpy(),
                steps_total=rows.column("steps").to_numpy(),
                trial_steps=(_unpack_list(rows.column("trial_steps"), trials, np.int32)
                             if "trial_steps" in rows.column_names else None),
                policy=_unpack_list(rows.column("policy"), n_states, np.int32) if n_states else None,
                finite=rows.column("finite").to_numpy(zero_copy_only=False) if "finite" in rows.column_names
                else None,
            )
            if np.any(np.diff(out[algo].seeds) <= 0) or np.any(out[algo].seeds[:1] < 0):
                raise UsageError(f"{path}: the seeds of {algo} are not distinct, non-negative and in order, "
                                 "as a run writes them; re-run the experiment")
            if bits.shape[0] != out[algo].seeds.shape[0] or not _counts_match(bits, out[algo].successes):
                raise UsageError(f"{path}: successes for {algo} do not match its success curves; "
                                 "re-run the experiment")
    except (pa.ArrowException, ValueError) as exc:
        raise UsageError(f"{path} has malformed columns ({exc}); re-run the experiment") from None
    return out


def _counts_match(bits: SuccessBits, successes: np.ndarray) -> bool:
    """Whether each row's set bits number its successes (padding bits are zero), a row group at a time."""
    return all(np.array_equal(successes[i : i + ROW_GROUP],
                              np.bitwise_count(bits.bits[i : i + ROW_GROUP]).sum(axis=1, dtype=np.int64))
               for i in range(0, len(bits), ROW_GROUP))


def _load_legacy(folder: Path, algos, trials: int) -> dict[str, AlgoResults]:
    """Run folders of release 0.1: curves.npz (success, steps) and policies.npz."""
    import zipfile

    def read(name):
        try:
            with np.load(folder / name) as npz:
                return {k: np.asarray(npz[k]) for k in npz.files}
        except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
            raise UsageError(f"{folder / name} is not a readable .npz file ({exc}); "
                             "re-run the experiment") from None

    curves = read("curves.npz")
    policies = read("policies.npz") if (folder / "policies.npz").is_file() else {}
    out = {}
    for algo in algos:
        if algo not in curves:
            raise UsageError(f"{folder / 'curves.npz'} has no array {algo!r}; re-run the experiment")
        success = curves[algo].astype(bool)
        if success.ndim != 2 or success.shape[1] != trials:
            raise UsageError(f"{folder / 'curves.npz'}[{algo!r}] has shape {success.shape}, "
                             f"expected [seeds, {trials}]")
        steps = curves.get(f"{algo}_steps")
        out[algo] = AlgoResults(
            seeds=policies.get("seeds", np.arange(success.shape[0])), success=success,
            successes=success.sum(1), first_success=np.where(success.any(1), success.argmax(1) + 1, -1),
            steps_total=steps.sum(1) if steps is not None else np.zeros(success.shape[0], np.int64),
            trial_steps=steps.astype(np.int32) if steps is not None else None,
            policy=policies[algo].astype(np.int32) if algo in policies else None,
        )
    return out


def load_grid_results(folder: str | Path, algos, trials: int, *, compact: bool = False
                      ) -> dict[str, AlgoResults]:
    """Per-seed results of `algos` from a grid run folder, new format or old.

    `compact`: success curves as `SuccessBits` and no per-trial steps or policies (what
    `compare` needs: 1/8 of the memory, and the file's bytes taken as they are)."""
    folder = Path(folder)
    if (folder / RESULTS_FILE).is_file():
        return _load_parquet(folder / RESULTS_FILE, algos, trials, compact)
    if (folder / "curves.npz").is_file():
        return _load_legacy(folder, algos, trials)
    raise UsageError(f"{folder} has neither {RESULTS_FILE} nor curves.npz; "
                     "pass a run folder written by 'jaxeac grid'")
