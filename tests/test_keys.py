"""Key expressions: every kind of ``bintrack.keys.KINDS`` is built by its ``Keys`` method and
parsed back by ``parse_key``, enumerated from the table itself; the built strings are pinned
(they are the bus format); the keys the README and docs/ name are kinds of the table, and the
docs' table of keys (docs/design.md) lists every kind."""

import inspect
import itertools
import re

import pytest

from bintrack.keys import KIND, KINDS, Keys, ParsedKey, parse_key
from support import REPO

FIELD_VALUES = {"sensor": "n1", "region": "r0c1", "service": "peer_agent", "instance": "p1"}

# The bus format, written out: a kind added to KINDS must be added here (the test below says so).
BUILT = {
    "raw": "bintrack/lab/raw/n1",
    "transition": "bintrack/lab/sensor/n1/transition",
    "state": "bintrack/lab/sensor/n1/state",
    "estimate": "bintrack/lab/peer/n1/estimate",
    "fusion_reports": "bintrack/lab/fusion/reports",
    "tracks": "bintrack/lab/tracks",
    "region_reports": "bintrack/lab/region/r0c1/fusion/reports",
    "region_tracks": "bintrack/lab/region/r0c1/tracks",
    "region_progress": "bintrack/lab/region/r0c1/progress",
    "region_alive": "bintrack/lab/region/r0c1/alive",
    "laser_objects": "bintrack/lab/laser/objects",
    "motion_velocity": "bintrack/lab/motion/velocity",
    "truth": "bintrack/lab/truth",
    "deployment": "bintrack/lab/deployment",
    "clock": "bintrack/lab/clock",
    "eos": "bintrack/lab/control/eos",
    "recent": "bintrack/lab/control/recent",
    "alive": "bintrack/lab/alive/peer_agent/p1",
    "progress": "bintrack/lab/control/progress/peer_agent/p1",
    "done": "bintrack/lab/control/done/peer_agent/p1",
}


def built(keys: Keys, kind: str) -> str:
    """The key of ``kind`` made by its own ``Keys`` method, with FIELD_VALUES."""
    return getattr(keys, kind)(*(FIELD_VALUES[f] for f in KIND[kind].fields))


def test_the_table_has_one_entry_per_kind_and_keys_one_builder_per_kind():
    assert len(KIND) == len(KINDS)
    builders = {name for name, _ in inspect.getmembers(Keys, inspect.isfunction) if not name.startswith("_")}
    assert builders - {"all", "build"} == set(KIND)
    for kind in KINDS:  # a builder's parameters are its kind's fields, in key order, each `*` by default
        parameters = list(inspect.signature(getattr(Keys, kind.kind)).parameters.values())[1:]
        assert tuple(p.name for p in parameters) == kind.fields, kind.kind
        assert all(p.default == "*" for p in parameters), kind.kind


@pytest.mark.parametrize("kind", [k.kind for k in KINDS])
def test_every_kind_builds_and_parses_back(kind):
    keys = Keys("lab")
    fields = {f: FIELD_VALUES[f] for f in KIND[kind].fields}
    key = built(keys, kind)
    assert key == keys.build(kind, **fields)
    assert parse_key(key) == ParsedKey("lab", kind, **fields)


def test_built_keys_are_the_bus_format():
    keys = Keys("lab")
    assert set(BUILT) == set(KIND), "a kind without its written-out key here, or one that is gone"
    assert {kind: built(keys, kind) for kind in BUILT} == BUILT


def test_no_two_kinds_share_a_key():
    keys = Keys("lab")
    for a, b in itertools.permutations(KINDS, 2):
        assert not _matches(built(keys, a.kind).split("/")[2:], b.chunks), (a.kind, b.kind)


def test_wildcards_for_subscriptions():
    k = Keys()
    assert k.all() == "bintrack/default/**"
    assert k.transition() == "bintrack/default/sensor/*/transition"
    assert k.alive() == "bintrack/default/alive/*/*"
    assert k.region_tracks() == "bintrack/default/region/*/tracks"
    assert k.progress("replay") == "bintrack/default/control/progress/replay/*"


@pytest.mark.parametrize("key", ["other/net/tracks", "bintrack/net/nothing", "bintrack/net/sensor/a/b/c", "bintrack",
                                 "bintrack//tracks", "bintrack/net/raw/", "bintrack/net/region//tracks",
                                 "bintrack/net/alive/replay", "bintrack/net/control/progress/replay",
                                 "bintrack/net/control/recent/x", "bintrack/net/region/r0/nothing"])
def test_unknown_keys_are_rejected(key):
    with pytest.raises(ValueError):
        parse_key(key)


@pytest.mark.parametrize("bad", ["a/b", "*", "x$", ""])
def test_bad_network_names_are_rejected(bad):
    with pytest.raises(ValueError):
        Keys(bad)


@pytest.mark.parametrize("bad", ["a/b", "**", "x$", "", "a b"])
def test_bad_sensor_ids_are_rejected(bad):
    with pytest.raises(ValueError):
        Keys("n").transition(bad)


@pytest.mark.parametrize("kind, field", [("region_tracks", "region"), ("alive", "service"), ("done", "instance")])
@pytest.mark.parametrize("bad", ["a/b", "**", "x?", ""])
def test_bad_region_service_and_instance_names_are_rejected(kind, field, bad):
    with pytest.raises(ValueError):
        Keys("n").build(kind, **{field: bad})


def test_a_field_the_kind_does_not_have_is_refused():
    with pytest.raises(TypeError, match="no field"):
        Keys("n").build("tracks", sensor="n1")


# --------------------------------------------------------------------------- the docs


DOCS = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
FIRST_CHUNKS = {k.chunks[0] for k in KINDS}


def _matches(chunks: list[str], pattern: tuple[str, ...]) -> bool:
    """Whether a key's ``chunks`` (``*`` and ``<…>`` stand for one chunk, ``**`` for any
    number) fit a kind's ``pattern``."""
    if not chunks:
        return not pattern
    head, rest = chunks[0], chunks[1:]
    if head == "**":
        return any(_matches(rest, pattern[i:]) for i in range(len(pattern) + 1))
    if not pattern:
        return False
    field = pattern[0].startswith("{")
    fits = head == "*" or (head.startswith("<") and head.endswith(">")) or head == pattern[0] or (field and head)
    return bool(fits) and _matches(rest, pattern[1:])


def _expand(text: str) -> list[str]:
    """``a/{b,c/d}`` → ``a/b``, ``a/c/d``; ``x/progress|done`` → ``x/progress``, ``x/done``."""
    brace = re.search(r"\{([^{}]*)\}", text)
    if brace:
        return [e for option in brace.group(1).split(",")
                for e in _expand(text[:brace.start()] + option + text[brace.end():])]
    bar = re.search(r"([^/|]+)((?:\|[^/|]+)+)", text)
    if bar:
        return [e for option in bar.group(0).split("|") for e in _expand(text[:bar.start()] + option + text[bar.end():])]
    return [text]


def doc_keys(text: str) -> list[str]:
    """The key expressions a document names in backticks: ``bintrack/<net>/…`` or a suffix of
    more than one chunk whose first chunk starts a kind (``sensor/*/transition``), query
    strings (``?after=T``) dropped."""
    found = []
    for span in re.findall(r"`([^`\s]+)`", text):
        span = span.split("?")[0].replace("…", "**")  # `region/<r>/…`: the region keys
        if span.endswith("/"):  # a folder (`laser/`), not a key
            continue
        if span.startswith("bintrack/"):
            suffix = span.split("/", 2)[2] if span.count("/") >= 2 else ""
        elif "/" in span and span.split("/")[0] in FIRST_CHUNKS:
            suffix = span
        else:
            continue
        found += [s for s in _expand(suffix) if s]
    return found


def test_every_key_the_docs_name_is_a_kind_of_the_table():
    named, unknown = 0, []
    for doc in DOCS:
        for key in doc_keys(doc.read_text()):
            named += 1
            # a kind, or a family of kinds by their first chunks (`control/done`: every done key)
            if not any(_matches(key.split("/") + ["**"], kind.chunks) for kind in KINDS):
                unknown.append(f"{doc.relative_to(REPO)}: `{key}`")
    assert named > 20  # the README's role table alone names more
    assert not unknown, "keys the table does not have:\n" + "\n".join(unknown)


def key_tables(text: str) -> list[list[list[str]]]:
    """The rows (lists of cells) of each markdown table whose first header cell is ``key``."""
    tables, rows = [], None
    for line in text.splitlines() + [""]:
        cells = [c.strip() for c in line.strip().strip("|").split("|")] if line.startswith("|") else None
        if cells is None:
            if rows is not None:
                tables.append(rows)
            rows = None
        elif rows is None and cells[0].lower() == "key":
            rows = []
        elif rows is not None and not set(cells[0]) <= set("-: "):
            rows.append(cells)
    return tables


def kind_of_cell(cell: str):
    """The kind a table's key cell names (`` `bintrack/<net>/raw/<sensor>` `` or `` `raw/{sensor}` ``),
    None if none or several."""
    key = cell.strip("`")
    key = key.split("/", 2)[2] if key.startswith("bintrack/") else key
    chunks = ["*" if c.startswith("{") or c.startswith("<") else c for c in key.split("/")]
    fitting = [kind for kind in KINDS if _matches(chunks, kind.chunks)]
    return fitting[0] if len(fitting) == 1 else None


def test_the_docs_key_tables_list_every_kind_as_the_table_has_it():
    """A docs table of keys (first header cell ``key``, a row per kind) lists every kind, once,
    and nothing else; a row that names a builder (``Keys.kind(fields)``) or a kind
    (`` `kind` ``) names its own."""
    tables = [(doc, rows) for doc in DOCS for rows in key_tables(doc.read_text())]
    assert tables, "no docs table of keys (first header cell `key`)"
    for doc, rows in tables:
        where = doc.relative_to(REPO)
        kinds = [kind_of_cell(row[0]) for row in rows]
        assert None not in kinds, f"{where}: {[row[0] for row, k in zip(rows, kinds) if k is None]} name no kind"
        listed = sorted(k.kind for k in kinds)
        assert listed == sorted(KIND), f"{where}: {sorted(set(listed) ^ set(KIND))} (once each)"
        for row, kind in zip(rows, kinds):
            for name, args in re.findall(r"Keys\.(\w+)\(([^)]*)\)", " ".join(row[1:])):
                assert (name, tuple(a.strip() for a in args.split(",") if a.strip())) == (kind.kind, kind.fields), \
                    f"{where}: {row[0]} is built by Keys.{kind.kind}{kind.fields}, not Keys.{name}({args})"
            named = [c.strip("`") for c in row[1:] if c.strip("`") in KIND]
            assert named in ([], [kind.kind]), f"{where}: {row[0]} is kind {kind.kind!r}, not {named}"


def test_the_docs_checks_catch_a_wrong_key_and_a_wrong_table():
    assert doc_keys("`sensor/*/transitions` and `bintrack/<net>/control/finished` and `tracks.csv`") == [
        "sensor/*/transitions", "control/finished"]
    assert not any(_matches("sensor/*/transitions".split("/") + ["**"], kind.chunks) for kind in KINDS)
    assert _expand("region/*/{fusion/reports,tracks}") == ["region/*/fusion/reports", "region/*/tracks"]
    assert _expand("control/progress|done") == ["control/progress", "control/done"]
    table = "| key | what |\n| --- | --- |\n| `tracks` | x |\n\nafter"
    assert key_tables(table) == [[["`tracks`", "x"]]]
    assert kind_of_cell("`bintrack/<net>/region/<r>/tracks`").kind == "region_tracks"
    assert kind_of_cell("`raw/{sensor}`").kind == "raw"
    assert kind_of_cell("`sensor/<s>/transitions`") is None
