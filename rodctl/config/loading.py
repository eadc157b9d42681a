"""Load a config: YAML file -> `--set` overrides -> one validation -> `ExperimentConfig`.

Every failure becomes a `ConfigError` whose message names the file, the dotted field path and
what was expected; the CLI prints it and exits with code 2, never a traceback.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NoReturn

import yaml
from pydantic import BaseModel, ValidationError

from rodctl.config.base import BOOL_FOR_NUMBER
from rodctl.config.experiment import ExperimentConfig
from rodctl.errors import UserError
from rodctl.registry import STAGES, load_plugins


class ConfigError(UserError):
    """A config that cannot be used. `str(err)` is the user-facing message."""


#: Deepest nesting a config may have (the real ones have 4): a guard against hostile files.
MAX_DEPTH = 32
#: Largest YAML file read (configs are a few kB; a file of 10,000 target poses about 0.5 MB).
MAX_YAML_BYTES = 8 << 20
#: Most values a YAML document may hold with every alias expanded (a 10,000-pose targets file
#: holds 40,000): a guard against alias bombs, which are tiny until expanded.
MAX_YAML_NODES = 200_000


def _refuse_yaml11(node: Any, value: Any, why: str) -> NoReturn:
    """A YAML 1.1 number that is not the one written (`construct_yaml_int` / `_float`)."""
    mark = node.start_mark
    raise yaml.YAMLError(
        f"{node.value!r} (line {mark.line + 1}, column {mark.column + 1}) is {value} in YAML "
        f"1.1 ({why}); write the number plainly, or quote it for a text"
    )


class _StrictLoader(yaml.SafeLoader):
    """`yaml.SafeLoader` that refuses duplicate keys (silently, the last would win) and
    nesting deeper than `MAX_DEPTH` (the parser would otherwise recurse until it crashes)."""

    def compose_node(self, parent: Any, index: Any) -> Any:
        self._depth = getattr(self, "_depth", 0) + 1
        try:
            if self._depth > MAX_DEPTH:
                mark = self.peek_event().start_mark
                raise yaml.YAMLError(
                    f"nesting deeper than {MAX_DEPTH} levels (line {mark.line + 1}, column "
                    f"{mark.column + 1})"
                )
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def construct_document(self, node: Any) -> Any:
        _check_expanded_size(node)
        return super().construct_document(node)

    def construct_yaml_int(self, node: Any) -> Any:
        # YAML 1.1 reads 010 as octal 8 and 12:30 as base 60 (750): numbers silently not the
        # ones written (YAML 1.2 dropped both). Refused, saying what it would have been.
        text = str(node.value).replace("_", "").lstrip("+-")
        if ":" in text or (len(text) > 1 and text[0] == "0" and text[1:].isdigit()):
            _refuse_yaml11(
                node, super().construct_yaml_int(node), "a leading 0 is octal, a ':' base 60"
            )
        return super().construct_yaml_int(node)

    def construct_yaml_float(self, node: Any) -> Any:
        # The same for YAML 1.1's base-60 floats: 1:30.5 is 90.5.
        if ":" in str(node.value):
            _refuse_yaml11(node, super().construct_yaml_float(node), "a ':' is base 60")
        return super().construct_yaml_float(node)

    def construct_mapping(self, node: Any, deep: bool = False) -> Any:
        seen: dict[Any, Any] = {}
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            if key in seen:
                mark = key_node.start_mark
                raise yaml.YAMLError(
                    f"duplicate key {key!r} (line {mark.line + 1}, column {mark.column + 1}; "
                    f"first at line {seen[key].line + 1})"
                )
            seen[key] = key_node.start_mark
        return super().construct_mapping(node, deep=deep)


_StrictLoader.add_constructor("tag:yaml.org,2002:int", _StrictLoader.construct_yaml_int)
_StrictLoader.add_constructor("tag:yaml.org,2002:float", _StrictLoader.construct_yaml_float)


def _check_expanded_size(root: Any) -> None:
    """Refuse a document holding more than `MAX_YAML_NODES` values once its aliases are
    expanded, or an alias to itself. Aliases share their node, so the count is memoised by node
    (iteratively, in post-order) and costs one visit per distinct node."""
    sizes: dict[int, int] = {}
    stack: list[tuple[Any, bool]] = [(root, False)]
    while stack:
        node, done = stack.pop()
        key = id(node)
        if done:
            children = _children(node)
            sizes[key] = 1 + sum(sizes[id(c)] for c in children)
            if sizes[key] > MAX_YAML_NODES:
                mark = node.start_mark
                raise yaml.YAMLError(
                    f"more than {MAX_YAML_NODES} values once its aliases are expanded (line "
                    f"{mark.line + 1}, column {mark.column + 1}): an alias bomb?"
                )
            continue
        if key in sizes:
            if sizes[key] < 0:
                raise yaml.YAMLError("an alias that refers to itself")
            continue
        sizes[key] = -1  # in progress
        stack.append((node, True))
        stack.extend((c, False) for c in _children(node) if sizes.get(id(c), 0) <= 0)


def _children(node: Any) -> list[Any]:
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    if isinstance(node, yaml.MappingNode):
        return [n for pair in node.value for n in pair]
    return []


def safe_load(text: str) -> Any:
    """`yaml.safe_load` with duplicate keys, excessive nesting, alias bombs and texts over
    `MAX_YAML_BYTES` refused (`yaml.YAMLError`)."""
    if len(text) > MAX_YAML_BYTES:
        raise yaml.YAMLError(f"larger than {MAX_YAML_BYTES >> 20} MiB")
    return yaml.load(text, Loader=_StrictLoader)  # noqa: S506 - a SafeLoader subclass


def read_yaml_text(path: Path, what: str) -> str:
    """The text of a YAML file, refused by size before anything is read or parsed.

    Raises:
        ConfigError: missing, not a regular file, larger than `MAX_YAML_BYTES`, unreadable or
            not UTF-8; the message starts with `what` (how the user named the file).
    """
    if not path.exists():
        raise ConfigError(f"{what}: no such file")
    if not path.is_file():
        raise ConfigError(f"{what}: not a file")
    try:
        with open(path, "rb") as f:
            raw = f.read(MAX_YAML_BYTES + 1)
    except OSError as exc:
        raise ConfigError(f"{what}: cannot read: {exc}") from None
    if len(raw) > MAX_YAML_BYTES:
        raise ConfigError(
            f"{what}: larger than {MAX_YAML_BYTES >> 20} MiB, too large to be a config; refused "
            "before parsing"
        )
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{what}: cannot read: {exc}") from None


def parse_yaml(text: str, what: str) -> Any:
    """`safe_load(text)`, every refusal a `ConfigError` starting with `what`."""
    try:
        return safe_load(text)
    except RecursionError:
        raise ConfigError(f"{what}: nested too deeply to be a config") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ConfigError(f"{what}: YAML syntax error{where}: {problem}") from None


def read_yaml(path: str | Path, what: str = "config") -> dict[str, Any]:
    """Read a YAML mapping from `path` with `safe_load` (the strict loader); `what` the file
    holds names it in the messages (a config, a topic mapping, a calibration...).

    Raises:
        ConfigError: the file is missing, unreadable, larger than `MAX_YAML_BYTES`, not YAML
            (or refused by `safe_load`), empty, or not a mapping.
    """
    path = Path(path)
    data = parse_yaml(read_yaml_text(path, str(path)), str(path))
    if data is None:
        # Most likely a file emptied by mistake; `{}` says "the defaults" on purpose.
        hint = "; to run every default on purpose, write `{}` in it" if what == "config" else ""
        raise ConfigError(f"{path}: the file is empty (no {what} keys){hint}")
    if not isinstance(data, dict):
        raise ConfigError(
            f"{path}: expected a mapping of {what} keys at the top level, got {type(data).__name__}"
        )
    return data


def parse_override(text: str) -> tuple[list[str], Any]:
    """Parse one `--set a.b.c=value` into (["a", "b", "c"], value); value is a YAML scalar/flow.

    Raises:
        ConfigError: no `=`, an empty key segment, or a value that is not valid YAML.
    """
    key, sep, raw = text.partition("=")
    key = key.strip()
    if not sep or not key:
        raise ConfigError(
            f"--set {text!r}: expected KEY=VALUE with a dotted key, e.g. rod.length=0.6"
        )
    parts = key.split(".")
    if any(not p.strip() for p in parts):
        raise ConfigError(f"--set {text!r}: empty segment in the dotted key {key!r}")
    try:
        value = safe_load(raw) if raw.strip() else None
    except (yaml.YAMLError, RecursionError) as exc:
        why = "" if isinstance(exc, RecursionError) else f": {str(exc).splitlines()[0]}"
        raise ConfigError(
            f"--set {text!r}: the value {raw[:40]!r} is not valid YAML{why}"
        ) from None
    return [p.strip() for p in parts], value


def _refuse_index_into_nothing(part: str, where: str, text: str) -> None:
    """A list index under a key the config does not set: a mapping {"0": v} made there would
    be no list at all (pydantic: 'Input should be a valid tuple')."""
    if part.isdigit():
        raise ConfigError(
            f"--set {text!r}: the config does not set {where}, so there is no list to index; "
            f"set the whole value (--set {where}=[...])"
        )


def apply_override(
    data: dict[str, Any],
    parts: list[str],
    value: Any,
    text: str,
    dotted: dict[str, frozenset[str]] | None = None,
) -> None:
    """Set `data[parts[0]][parts[1]]... = value`, creating mappings on the way; lists by index.

    Setting a section's `type` to another type replaces the section: the old type's keys mean
    nothing to the new one (`--set controller.type=pinv` drops MFAC's `weights`). Keys set by
    later `--set`s are applied to the new section. A section written without `type` has the
    default type of its stage.
    `dotted`: top-level sections whose keys have dots in them, with the fields their values
    take (a sweep's `parameters`, `SweepConfig.DOTTED_SECTIONS`): a key not there yet is every
    part up to the first such field (`parameters.rod.length.values` -> key `rod.length`).
    """
    node: Any = data
    i = 0
    while i < len(parts):
        start = i
        part, i = _key_at(node, parts, i)
        fields = (dotted or {}).get(parts[0]) if start == 1 else None
        if fields is not None and isinstance(node, dict) and part not in node:
            end = next((k for k in range(i, len(parts)) if parts[k] in fields), len(parts))
            part, i = ".".join(parts[1:end]), end
        last = i == len(parts)
        where = ".".join(parts[:i])
        if isinstance(node, dict):
            if last and part == "type" and _section_type(node, parts[:-1]) not in (None, value):
                node.clear()
                node[part] = value
            elif last:
                node[part] = value
            else:
                nxt = node.get(part)
                if nxt is None:
                    _refuse_index_into_nothing(parts[i], where, text)
                    nxt = node[part] = {}
                node = nxt
        elif isinstance(node, list):
            try:
                idx = int(part)
                node[idx]  # noqa: B018 - bounds check
            except (ValueError, IndexError):
                raise ConfigError(
                    f"--set {text!r}: {where!r} indexes a list of {len(node)} items; "
                    f"expected an integer index in [0, {len(node) - 1}]"
                ) from None
            if last:
                node[idx] = value
            else:
                node = node[idx]
        else:
            raise ConfigError(
                f"--set {text!r}: {'.'.join(parts[:start])!r} is a value ({node!r}), not a section"
            )


def _key_at(node: Any, parts: list[str], i: int) -> tuple[str, int]:
    """The key of `node` that `parts[i:]` starts with, and the index after it: `parts[i]`, or
    the longest run of parts that a key with dots in it spells (a sweep's `parameters` are
    named `estimator.p0`: `--set parameters.estimator.p0=...` reaches that key)."""
    if isinstance(node, dict) and parts[i] not in node:
        for j in range(len(parts), i + 1, -1):
            if ".".join(parts[i:j]) in node:
                return ".".join(parts[i:j]), j
    return parts[i], i + 1


def _section_type(section: dict[str, Any], path: list[str]) -> Any:
    """The type a section has now: its `type`, or its stage's default when it has other keys."""
    if "type" in section:
        return section["type"]
    if section and path and path[-1] in STAGES:
        return STAGES[path[-1]].default
    return None


def _dotted(loc: tuple[Any, ...], data: Any) -> str:
    """Turn a pydantic error location into the dotted path a user writes in YAML.

    Discriminated unions and validators add location entries that are not keys in the input
    (the union tag, e.g. ``controller.mfac.weights``); follow the input data and keep only the
    entries that are really there, plus the last one (a missing key is, by definition, absent).
    """
    out, _, last_there = _input_entries(loc, data)
    if loc and not last_there and not str(loc[-1]).startswith("function-"):
        out.append(str(loc[-1]))
    return ".".join(out) or "(top level)"


def _input_entries(loc: tuple[Any, ...], data: Any) -> tuple[list[str], Any, bool]:
    """The entries of `loc` that are keys or indices of the input (union tags dropped), the
    value they lead to, and whether the last entry of `loc` was one of them."""
    out: list[str] = []
    node, there = data, False
    for part in loc:
        there = False
        if isinstance(node, dict) and part in node:
            node, there = node[part], True
        elif isinstance(node, list | tuple) and isinstance(part, int) and 0 <= part < len(node):
            node, there = node[part], True
        if there:
            out.append(str(part))
    return out, node, there


def _list_at(loc: tuple[Any, ...], data: Any) -> tuple[str, Any]:
    """The dotted path of the input entries along `loc` (union tags dropped) and the value
    there."""
    out, node, _ = _input_entries(loc, data)
    return ".".join(out) or "(top level)", node


def _tuple_length(err: Any, data: Any) -> tuple[str, tuple, int, int] | None:
    """(list's path, the schema branch, length it wanted at least, length given) when `err`
    says a fixed-length list (a tuple) is too short (an item `missing`) or too long, else
    None. A list with only a maximum length keeps pydantic's "at most" message."""
    loc = tuple(err["loc"])
    if err["type"] == "missing" and loc and isinstance(loc[-1], int):
        path, given = _list_at(loc[:-1], data)
        if isinstance(given, list | tuple) and loc[-1] >= len(given):
            return path, loc[:-1], loc[-1] + 1, len(given)
    ctx = err.get("ctx") or {}
    if err["type"] == "too_long" and ctx.get("field_type") == "Tuple":
        path, _ = _list_at(loc, data)
        return path, loc, ctx["max_length"], ctx["actual_length"]
    return None


def _union_branches(err: Any, data: Any) -> list[tuple[tuple, Any]]:
    """[(the location of a union, the member's tag)] along the error's location, outermost
    first: the entries that are neither a key nor an index of the input (pydantic's names of
    union members; a discriminated union's tag too, whose union then has one member)."""
    loc = tuple(err["loc"])
    node, found = data, []
    for i, part in enumerate(loc):
        if isinstance(node, dict) and part in node:
            node = node[part]
        elif isinstance(node, list | tuple) and isinstance(part, int) and 0 <= part < len(node):
            node = node[part]
        elif not isinstance(part, str):
            break
        elif i < len(loc) - 1 or isinstance(node, list | tuple) or err["type"] not in _KEY_ERRORS:
            found.append((loc[:i], part))  # (the last entry of a key error is the key)
    return found


#: Errors whose location ends with a key of the input's mapping, not a union member's tag.
_KEY_ERRORS = ("missing", "extra_forbidden")


def _closest_branches(errors: list[Any], data: Any) -> list[Any]:
    """The errors of the union members nearest the input, where a list's length is at stake.

    A plain union (`Pose | DualPose`, `list[Pose] | list[DualPose]`) reports every member's
    errors; when some members complain of a list's length, keep the members that do not (the
    input has the length they take: their errors are the news), else those whose errors name
    the fewest places (so `[[x, y, t], [x, y]]` is told that item 1 is short, not also that
    item 0 is not a 6-value pose); the lengths of those kept are merged by `_error_lines`."""
    members: dict[tuple, dict[Any, list[Any]]] = {}
    for err in errors:
        for union, tag in _union_branches(err, data):
            members.setdefault(union, {}).setdefault(tag, []).append(err)
    dropped: set[int] = set()
    for branches in members.values():
        if len(branches) < 2:
            continue
        rank = {tag: _branch_rank(errs, data) for tag, errs in branches.items()}
        if not any(short for short, _ in rank.values()):
            continue  # no list length at stake: every member's errors, as pydantic gives them
        best = min(rank.values())
        for tag, errs in branches.items():
            if rank[tag] != best:
                dropped.update(id(e) for e in errs)
    return [e for e in errors if id(e) not in dropped]


def _branch_rank(errs: list[Any], data: Any) -> tuple[bool, int]:
    """(whether a union member complains of a list's length, how many places it names)."""
    places = set()
    short = False
    for err in errs:
        length = _tuple_length(err, data)
        short = short or length is not None
        places.add(length[0] if length is not None else _dotted(tuple(err["loc"]), data))
    return short, len(places)


def _error_lines(errors: list[Any], data: Any) -> list[str]:
    """One line per offending field. A list of the wrong length says so once ("expected 3 or 6
    values, got 2") instead of one `missing` per absent item and per union member."""
    lines: list[str] = []
    lengths: dict[str, tuple[set[int], int]] = {}
    wanted: dict[tuple[str, tuple], int] = {}
    for err in _closest_branches(errors, data):
        length = _tuple_length(err, data)
        if length is not None:
            path, branch, want, got = length
            if path not in lengths:
                lengths[path] = (set(), got)
                lines.append(path)  # placeholder, filled below
            wanted[path, branch] = max(wanted.get((path, branch), 0), want)
            continue
        lines.append(_error_line(err, data))
    for (path, _), want in wanted.items():
        lengths[path][0].add(want)
    for i, line in enumerate(lines):
        if line in lengths:
            wants, got = lengths[line]
            counts = " or ".join(str(n) for n in sorted(wants))
            lines[i] = f"{line}: expected a list of {counts} values, got {got}"
    return list(dict.fromkeys(lines))


def _error_line(err: Any, data: Any) -> str:
    """`path: what is wrong (got ...)` for one pydantic error."""
    msg, loc = err["msg"], tuple(err["loc"])
    if err["type"] == BOOL_FOR_NUMBER:  # raised by a model: the field is in the context
        where, _ = _list_at(loc, data)
        prefix = "" if where == "(top level)" else f"{where}."
        field, given = err["ctx"]["field"], err["ctx"]["given"]
        return f"{prefix}{field}: expected a number, not a boolean (got {given!r})"
    ends_in_tag = any(len(union) == len(loc) - 1 for union, _ in _union_branches(err, data))
    # A union member's tag is not a key to write: `pose: Input should be a valid tuple`, once.
    path = _list_at(loc, data)[0] if ends_in_tag else _dotted(loc, data)
    if msg.startswith("Value error, "):
        msg = msg[len("Value error, ") :]
    if err["type"] == "extra_forbidden":
        msg = "unknown key (check the spelling; `rodctl config schema` lists every key)"
    elif err["type"] == "missing":
        msg = "required key is missing"
    elif err["type"] == "int_parsing" and (hint := _whole_number_hint(err.get("input"))):
        msg = hint
    else:
        given = err.get("input")
        if not isinstance(given, dict | list) and err["type"] != "union_tag_invalid":
            msg = f"{msg} (got {given!r})"
    return f"{path}: {msg}"


def _whole_number_hint(value: Any) -> str | None:
    """What to write for a whole number given as text that reads as one (YAML 1.1 reads
    `1e9`, without a dot, as text), else None."""
    try:
        number = float(value) if isinstance(value, str) else math.nan
    except ValueError:
        return None
    if not math.isfinite(number):
        return None
    if number.is_integer() and abs(number) < 1e18:
        return f"expected a whole number, got the text {value!r}: write {int(number)}"
    return f"expected a whole number, got {value!r}"


def format_validation_error(exc: ValidationError, data: Any, source: str) -> str:
    """One short paragraph naming each offending field, what was expected and what was given."""
    lines = _error_lines(exc.errors(include_url=False), data)
    head = [f"{source}: invalid config", *(f"  {line}" for line in lines[:8])]
    if len(lines) > 8:
        head.append(f"  ... and {len(lines) - 8} more")
    return "\n".join(head)


def validate_config(data: dict[str, Any], source: str, model: type[BaseModel] = ExperimentConfig):
    """Validate a raw mapping into `model`; `source` names it in error messages.

    Plug-ins are loaded first (once per process), so their types validate like built-ins.
    """
    load_plugins()
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(format_validation_error(exc, data, source)) from None


def config_source(path: str | Path | None, overrides: Sequence[str] | None) -> str:
    """How error messages name a config: its file, plus the overrides applied to it."""
    source = str(path) if path is not None else "(defaults)"
    if overrides:
        source += " with " + " ".join(f"--set {o}" for o in overrides)
    return source


def load_config(
    path: str | Path | None,
    overrides: Sequence[str] | None = None,
    model: type[BaseModel] = ExperimentConfig,
) -> Any:
    """Load `path` (None: embedded defaults only), apply `--set` overrides, validate once.

    Returns an instance of `model` (an `ExperimentConfig` unless told otherwise).
    """
    data: dict[str, Any] = read_yaml(path) if path is not None else {}
    dotted = getattr(model, "DOTTED_SECTIONS", None)
    for text in overrides or []:
        parts, value = parse_override(text)
        apply_override(data, parts, value, text, dotted)
    return validate_config(data, config_source(path, overrides), model)


#: libyaml's emitter where PyYAML was built with it: the same bytes as `yaml.SafeDumper` for every
#: shipped config (tests/test_config.py), 4x cheaper (issue 24: 2.7 -> 0.64 ms a dump).
_DUMPER: type = getattr(yaml, "CSafeDumper", yaml.SafeDumper)


def dump_config(cfg: BaseModel, *, clean: bool = False) -> str:
    """The resolved config as YAML, every default filled in but the physics switched off (left out
    so older logs stay byte-identical; `rodctl config schema` lists every key); loads back to an
    equal config.

    Args:
        clean: for display, print floats with 12 significant digits (-0.02, not
            -0.020000000000000004). Run directories and logs keep the exact values.
    """
    data = cfg.model_dump(mode="json")
    if clean:
        data = _clean_floats(data)
    return yaml.dump(data, Dumper=_DUMPER, sort_keys=False, default_flow_style=None)


def _clean_floats(value: Any) -> Any:
    if isinstance(value, float):
        return float(f"{value:.12g}")
    if isinstance(value, dict):
        return {k: _clean_floats(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_clean_floats(v) for v in value]
    return value
