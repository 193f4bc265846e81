"""The Modelica library ``modelica/HarmonicDrive`` is the twin of the C FMU: same interface, valid Modelica.

No Modelica tool (OpenModelica, Dymola) is available where the tests run, so:

1. **Interface.** A small declaration reader (comments removed, strings masked, one component per declaration,
   parenthesised modifiers matched) reads the public components of ``HarmonicDrive.Plant`` and every parameter,
   input and output is compared with

   - the variable table ``fmu_build/variables.py`` (always), and
   - the modelDescription.xml of the built FMUs, FMI 2.0 and FMI 3.0 (fixture ``fmu_any`` of conftest.py),

   for type (Real / Integer / Boolean), causality (``parameter`` / ``input`` / ``output`` prefix), unit, start value
   (the binding of a parameter, the ``start`` of the input) and min / max. A public parameter, input or output of
   the Plant that the FMU does not have fails too. Every failure names the variable and both values.
2. **Syntax, always**: a structural check needing no package (every file one class whose name matches its file,
   ``within`` matching the directory, balanced ``class ... end class;`` blocks, brackets and string quotes,
   ``package.order`` listing exactly the classes present).
3. **Syntax and semantics with real Modelica front ends** from PyPI, each test skipped with its reason when its
   package is missing:

   - ``rumoca`` (a Modelica compiler with a Python API): every file parses; ``HarmonicDrive.Plant`` compiles to a
     balanced system whose parameters (values, units, ranges) and input are the table's; the example
     ``HarmonicDrive.Examples.PulseTrain`` compiles and simulates (arm advances, bodies come to rest, energy
     balance), and, with the FMU, the Modelica plant driven by the same pulse train agrees with the FMU.
   - ``pymoca`` (an ANTLR Modelica grammar): every file parses.
"""
from __future__ import annotations

import math
import re
import shutil
from dataclasses import dataclass
from pathlib import Path

import pytest

from fmu_build.variables import VARIABLES

ROOT = Path(__file__).resolve().parents[1]
MODELICA_DIR = ROOT / "modelica"
LIBRARY = MODELICA_DIR / "HarmonicDrive"
PLANT_FILE = LIBRARY / "Plant.mo"
PLANT_CLASS = "Plant"  # HarmonicDrive.Plant: the twin of the FMU
MO_FILES = sorted(LIBRARY.rglob("*.mo"))

CHECKED_CAUSALITIES = ("parameter", "input", "output")
TABLE = {v.name: v for v in VARIABLES if v.causality in CHECKED_CAUSALITIES}


# ------------------------------------------------------------------------------------ a small Modelica reader --

def strip_comments(text: str) -> str:
    """``text`` without ``//`` and ``/* */`` comments (string literals kept, line breaks kept)."""
    out: list[str] = []
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if c == '"':
            j = i + 1
            while j < n and text[j] != '"':
                j += 2 if text[j] == "\\" else 1
            if j >= n:
                raise ValueError(f"unterminated string literal starting at offset {i}")
            out.append(text[i:j + 1])
            i = j + 1
        elif text.startswith("//", i):
            j = text.find("\n", i)
            i = n if j < 0 else j
        elif text.startswith("/*", i):
            j = text.find("*/", i + 2)
            if j < 0:
                raise ValueError(f"unterminated /* comment starting at offset {i}")
            out.append("\n" * text.count("\n", i, j))
            i = j + 2
        else:
            out.append(c)
            i += 1
    return "".join(out)


def mask_strings(text: str) -> tuple[str, list[str]]:
    """Replaces every string literal (comments already removed) by ``@S<k>@``; returns the text and the strings."""
    strings: list[str] = []

    def repl(m: re.Match) -> str:
        strings.append(m.group(0)[1:-1])
        return f"@S{len(strings) - 1}@"

    return re.sub(r'"(?:[^"\\]|\\.)*"', repl, text, flags=re.S), strings


def split_top_level(text: str, sep: str) -> list[str]:
    """Splits at ``sep`` outside (), [] and {}."""
    parts, depth, start = [], 0, 0
    for i, c in enumerate(text):
        if c in "([{":
            depth += 1
        elif c in ")]}":
            depth -= 1
        elif c == sep and depth == 0:
            parts.append(text[start:i])
            start = i + 1
    parts.append(text[start:])
    return parts


def matching_paren(text: str, i: int) -> int:
    """Index of the ``)`` closing the ``(`` at ``text[i]``."""
    depth = 0
    for j in range(i, len(text)):
        if text[j] == "(":
            depth += 1
        elif text[j] == ")":
            depth -= 1
            if depth == 0:
                return j
    raise ValueError(f"unbalanced parenthesis in {text!r}")


_INT = re.compile(r"[+-]?\d+")
_FLOAT = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")


def literal(expr: str, strings: list[str]):
    """The value of a literal: str, bool, int or float; anything else is returned as ``Expr('...')``."""
    e = expr.strip()
    m = re.fullmatch(r"@S(\d+)@", e)
    if m:
        return strings[int(m.group(1))]
    if e in ("true", "false"):
        return e == "true"
    if _INT.fullmatch(e):
        return int(e)
    if _FLOAT.fullmatch(e):
        return float(e)
    return Expr(e)


@dataclass(frozen=True)
class Expr:
    """A modifier or binding that is not a literal (the checked values must be literals)."""
    text: str

    def __repr__(self) -> str:
        return f"expression {self.text!r}"


@dataclass
class Decl:
    name: str
    type: str
    prefixes: tuple[str, ...]
    modifiers: dict
    binding: object
    public: bool

    @property
    def causality(self) -> str:
        for c in ("parameter", "constant", "input", "output"):
            if c in self.prefixes:
                return c
        return "local"

    @property
    def start(self):
        return self.binding if self.binding is not None else self.modifiers.get("start")


_PREFIXES = ("final", "inner", "outer", "replaceable", "redeclare", "flow", "stream", "discrete", "parameter",
             "constant", "input", "output")
_SECTION = re.compile(r"\b(?:initial\s+)?(?:equation|algorithm)\b")


def class_body(text: str, name: str) -> str:
    """The text between ``<restriction> name`` and ``end name;`` (comments removed, strings masked)."""
    m = re.search(rf"\b(?:model|block|class)\s+{name}\b", text)
    assert m, f"no 'model {name}' in the file"
    end = re.search(rf"\bend\s+{name}\s*;", text[m.end():])
    assert end, f"no 'end {name};' after 'model {name}'"
    return text[m.end():m.end() + end.start()]


def parse_declarations(mo_text: str, class_name: str) -> dict[str, Decl]:
    """Reads the component declarations of one class (its declaration part, before the first equation or
    algorithm section). One component per declaration is required (``Real a, b;`` raises)."""
    text, strings = mask_strings(strip_comments(mo_text))
    body = class_body(text, class_name)
    body = re.sub(r"^\s*@S\d+@", "", body)  # the class description string
    sect = _SECTION.search(body)
    decl_part = body[:sect.start()] if sect else body
    decls: dict[str, Decl] = {}
    public = True
    for stmt in split_top_level(decl_part, ";"):
        s = stmt.strip()
        while True:  # visibility keywords are not terminated by ';'
            m = re.match(r"(public|protected)\b\s*", s)
            if not m:
                break
            public = m.group(1) == "public"
            s = s[m.end():]
        if not s or re.match(r"(extends|import|annotation)\b", s):
            continue
        words = s.split()
        prefixes = []
        while words and words[0] in _PREFIXES:
            prefixes.append(words.pop(0))
        rest = " ".join(words)
        m = re.match(r"([A-Za-z_][\w.]*)\s+([A-Za-z_]\w*)\s*", rest)
        if not m:
            raise ValueError(f"declaration not understood by the test's reader: {stmt.strip()!r}")
        type_, name, tail = m.group(1), m.group(2), rest[m.end():]
        modifiers: dict = {}
        if tail.startswith("("):
            j = matching_paren(tail, 0)
            for item in split_top_level(tail[1:j], ","):
                if not item.strip():
                    continue
                key, eq, value = item.partition("=")
                if not eq:
                    raise ValueError(f"{name}: modifier {item.strip()!r} not understood")
                key = re.sub(r"^\s*(final|each)\s+", "", key).strip()
                modifiers[key] = literal(value, strings)
            tail = tail[j + 1:].strip()
        if tail.startswith(",") or tail.startswith("["):
            raise ValueError(f"write one scalar component per declaration: {stmt.strip()!r}")
        binding = None
        tail = re.sub(r"\bannotation\s*\(.*$", "", tail, flags=re.S).strip()
        tail = re.sub(r"@S\d+@\s*$", "", tail).strip()  # description string
        if tail.startswith("="):
            binding = literal(tail[1:], strings)
        elif tail:
            raise ValueError(f"{name}: declaration tail {tail!r} not understood")
        if name in decls:
            raise ValueError(f"{name} is declared twice in {class_name}")
        decls[name] = Decl(name, type_, tuple(prefixes), modifiers, binding, public)
    return decls


# ------------------------------------------------------------------------------------------ the comparison --

@dataclass(frozen=True)
class RefVar:
    """One variable of the reference (the table or a modelDescription), in Modelica terms."""
    name: str
    type: str  # Real / Integer / Boolean
    causality: str
    unit: str | None
    start: object
    min: object
    max: object


def _modelica_type(fmi_type: str) -> str:
    if fmi_type in ("Real", "Float64", "Float32"):
        return "Real"
    if fmi_type == "Integer" or re.fullmatch(r"U?Int(8|16|32|64)", fmi_type):
        return "Integer"
    if fmi_type == "Boolean":
        return "Boolean"
    raise AssertionError(f"FMI type {fmi_type} has no Modelica counterpart here")


def _value(text, type_: str):
    """A modelDescription attribute string as a Python value of the variable's type."""
    if text is None:
        return None
    if type_ == "Boolean":
        return text in ("true", "1", True)
    if type_ == "Integer":
        return int(text)
    return float(text)


def refs_from_table() -> dict[str, RefVar]:
    return {v.name: RefVar(v.name, v.type, v.causality, v.unit, v.start, v.lo, v.hi) for v in TABLE.values()}


def refs_from_model_description(fmu: Path) -> dict[str, RefVar]:
    from fmpy import read_model_description

    md = read_model_description(str(fmu))
    refs = {}
    for v in md.modelVariables:
        if v.causality not in CHECKED_CAUSALITIES:
            continue
        t = _modelica_type(v.type)
        unit = v.unit if v.unit is not None else (v.declaredType.unit if v.declaredType is not None else None)
        refs[v.name] = RefVar(v.name, t, v.causality, unit, _value(v.start, t), _value(v.min, t), _value(v.max, t))
    return refs


def _same(a, b) -> bool:
    if a is None or b is None or isinstance(a, (str, Expr)) or isinstance(b, (str, Expr)):
        return a == b
    if isinstance(a, bool) or isinstance(b, bool):
        return isinstance(a, bool) and isinstance(b, bool) and a == b
    return math.isclose(float(a), float(b), rel_tol=1e-12, abs_tol=0.0)


def mismatches(ref: RefVar, decls: dict[str, Decl], source: str) -> list[str]:
    """Every way the Plant's declaration of ``ref.name`` differs from ``ref`` (empty: identical)."""
    n = ref.name
    d = decls.get(n)
    if d is None:
        return [f"{n}: in {source} but not declared in HarmonicDrive.{PLANT_CLASS} ({PLANT_FILE.name})"]
    if not d.public:
        return [f"{n}: declared protected in HarmonicDrive.{PLANT_CLASS}, must be public"]
    out = []
    if d.type != ref.type:
        out.append(f"{n}: type {ref.type} in {source}, {d.type} in Modelica")
    if d.causality != ref.causality:
        out.append(f"{n}: causality {ref.causality} in {source}, {d.causality} in Modelica")
    unit = d.modifiers.get("unit")
    if unit != ref.unit:
        out.append(f"{n}: unit {ref.unit!r} in {source}, {unit!r} in Modelica")
    if ref.causality in ("parameter", "input"):
        start = d.start
        if not _same(start, ref.start):
            what = "value (binding)" if ref.causality == "parameter" else "start"
            out.append(f"{n}: start {ref.start!r} in {source}, {what} {start!r} in Modelica")
    for attr in ("min", "max"):
        mine, theirs = d.modifiers.get(attr), getattr(ref, attr)
        if not _same(mine, theirs):
            out.append(f"{n}: {attr} {theirs!r} in {source}, {mine!r} in Modelica")
    return out


def extra_components(refs: dict[str, RefVar], decls: dict[str, Decl]) -> list[str]:
    return [f"{d.name}: public {d.causality} of HarmonicDrive.{PLANT_CLASS} that the FMU does not have"
            for d in decls.values()
            if d.public and d.causality in CHECKED_CAUSALITIES and d.name not in refs]


@pytest.fixture(scope="module")
def plant_decls() -> dict[str, Decl]:
    return parse_declarations(PLANT_FILE.read_text(encoding="utf-8"), PLANT_CLASS)


# ------------------------------------------------------------------------------------------- interface tests --

def test_reader_reads_the_plant(plant_decls):
    """The reader sees the whole declaration part: the table's variables and the protected internals."""
    assert set(TABLE) <= set(plant_decls), sorted(set(TABLE) - set(plant_decls))
    assert any(not d.public for d in plant_decls.values()), "no protected declarations read"
    assert plant_decls["J_m"].binding == 2e-5 and plant_decls["J_m"].modifiers["unit"] == "kg.m2"


@pytest.mark.parametrize("name", sorted(TABLE))
def test_variable_matches_table(name, plant_decls):
    problems = mismatches(refs_from_table()[name], plant_decls, "fmu_build/variables.py")
    assert not problems, "\n".join(problems)


def test_no_extra_interface_variables(plant_decls):
    problems = extra_components(refs_from_table(), plant_decls)
    assert not problems, "\n".join(problems)


def test_interface_matches_model_description(fmu_any, plant_decls):
    """Every parameter, input and output of the built FMU's modelDescription.xml (FMI 2 and 3) is in the Plant
    with the same type, causality, unit, start and range, and the Plant has no others."""
    refs = refs_from_model_description(fmu_any)
    assert set(refs) == set(TABLE), "modelDescription and variables.py disagree on the variable set"
    source = f"modelDescription.xml of {fmu_any.name} ({fmu_any.parent.name})"
    problems = [p for ref in refs.values() for p in mismatches(ref, plant_decls, source)]
    problems += extra_components(refs, plant_decls)
    assert not problems, "\n".join(problems)


def test_a_changed_start_value_is_caught(plant_decls):
    """The comparison can fail: a copy of Plant.mo with one changed start value, unit, range or causality is
    reported, naming the variable."""
    text = PLANT_FILE.read_text(encoding="utf-8")
    table = refs_from_table()
    cases = [
        ("= 2e-5 \"Motor", "= 3e-5 \"Motor", "J_m", "start"),
        ('q_l(unit = "rad")', 'q_l(unit = "deg")', "q_l", "unit"),
        ("min = 1e-3, max = 1e15", "min = 1e-3, max = 1e14", "K_s", "max"),
        ("input Real motor_torque", "parameter Real motor_torque", "motor_torque", "causality"),
        ("output Integer encoder_count", "output Real encoder_count", "encoder_count", "type"),
        ("= 12566 \"Motor", "= 12567 \"Motor", "encoder_counts_per_rev", "start"),
    ]
    for old, new, name, what in cases:
        assert text.count(old) == 1, f"mutation anchor {old!r} not found once in Plant.mo"
        decls = parse_declarations(text.replace(old, new), PLANT_CLASS)
        problems = mismatches(table[name], decls, "table")
        assert any(p.startswith(f"{name}: {what}") for p in problems), (name, what, problems)


# ---------------------------------------------------------------------------------- syntax without packages --

_CLASS_OPEN = re.compile(r"\b(?:(?:partial|encapsulated|final|expandable|operator|pure|impure)\s+)*"
                         r"(model|package|block|class|function|record|connector|type)\s+([A-Za-z_]\w*)\b"
                         r"(?!\s*=)")
_CLASS_END = re.compile(r"\bend\s+([A-Za-z_]\w*)\s*;")


def _top_class(path: Path) -> tuple[str | None, str]:
    """(within, name of the file's class); asserts the file's block structure."""
    text, _ = mask_strings(strip_comments(path.read_text(encoding="utf-8")))
    for o, c in ("()", "[]", "{}"):
        assert text.count(o) == text.count(c), f"{path}: unbalanced {o}{c}"
    events = sorted([(m.start(), "open", m.group(2)) for m in _CLASS_OPEN.finditer(text)]
                    + [(m.start(), "close", m.group(1)) for m in _CLASS_END.finditer(text)
                       if m.group(1) not in ("if", "for", "when", "while")])
    stack: list[str] = []
    top: list[str] = []
    for _, kind, name in events:
        if kind == "open":
            if not stack:
                top.append(name)
            stack.append(name)
        else:
            assert stack and stack[-1] == name, f"{path}: 'end {name};' closes {stack[-1] if stack else 'nothing'}"
            stack.pop()
    assert not stack, f"{path}: class {stack[-1]} is never closed"
    assert len(top) == 1, f"{path}: must hold exactly one top-level class, has {top}"
    within = re.match(r"\s*within\s+([\w.]*)\s*;", text)
    return (within.group(1) if within else None), top[0]


@pytest.mark.parametrize("path", MO_FILES, ids=lambda p: str(p.relative_to(MODELICA_DIR)))
def test_structure(path):
    """Lightweight structural check (no parser needed): file name, class name and ``within`` agree."""
    within, name = _top_class(path)
    rel = path.relative_to(MODELICA_DIR)
    if path.name == "package.mo":
        expected_name = rel.parent.name
        expected_within = ".".join(rel.parent.parts[:-1]) or None
    else:
        expected_name = path.stem
        expected_within = ".".join(rel.parent.parts)
    assert name == expected_name, f"{rel}: class {name}, expected {expected_name}"
    assert within == expected_within, f"{rel}: within {within!r}, expected {expected_within!r}"


@pytest.mark.parametrize("package", sorted(p.parent for p in LIBRARY.rglob("package.mo")),
                         ids=lambda p: str(p.relative_to(MODELICA_DIR)))
def test_package_order(package):
    order = package / "package.order"
    assert order.is_file(), f"{order} missing"
    listed = [line.strip() for line in order.read_text(encoding="utf-8").splitlines() if line.strip()]
    present = sorted([p.stem for p in package.glob("*.mo") if p.name != "package.mo"]
                     + [d.name for d in package.iterdir() if (d / "package.mo").is_file()])
    assert sorted(listed) == present, f"{order}: lists {listed}, the directory holds {present}"


def test_documentation():
    """The package and the Plant are documented with what the brief asks for."""
    pkg = (LIBRARY / "package.mo").read_text(encoding="utf-8")
    plant = PLANT_FILE.read_text(encoding="utf-8")
    assert "Documentation(info" in pkg and "Documentation(info" in plant
    for needle in ("r = q_l/q_m", "K* = K_s/f_m", "J_l* = J_l/J_m", "f_l* = f_l/f_m", "T_c = sqrt(J_m/f_m)",
                   "12566", "fmu_build", "HarmonicDrive.Plant"):
        assert needle in pkg, f"package documentation lacks {needle!r}"


# ------------------------------------------------------------------------------------ rumoca (a compiler) --

def _rumoca():
    return pytest.importorskip("rumoca", reason="rumoca (Modelica compiler, PyPI 'rumoca') is not installed")


@pytest.mark.parametrize("path", MO_FILES, ids=lambda p: str(p.relative_to(MODELICA_DIR)))
def test_rumoca_parses(path):
    rm = _rumoca()
    errors = [d for d in rm.validate(str(path)) if d.level == "error"]
    assert not errors, f"{path}:\n" + "\n".join(f"line {d.line}: {d.message}" for d in errors)


@pytest.fixture(scope="module")
def rumoca_session():
    rm = _rumoca()
    return rm, rm.Session(roots=[str(MODELICA_DIR)])


def test_rumoca_compiles_plant(rumoca_session):
    """A real compiler reads the same interface as the test's reader: parameters with the table's values, units
    and ranges, the one input; the system is balanced."""
    rm, session = rumoca_session
    m = session.load(str(PLANT_FILE), model=f"HarmonicDrive.{PLANT_CLASS}")
    st = m.structure()
    assert st.is_balanced, f"{st.n_equations} equations for {st.n_unknowns} unknowns"
    params = [v for v in TABLE.values() if v.causality == "parameter"]
    assert sorted(m.parameters.names) == sorted(v.name for v in params)
    problems = []
    for v in params:
        p = m.parameters[v.name]
        if not _same(p.value, v.start):
            problems.append(f"{v.name}: value {p.value!r} (rumoca), {v.start!r} (table)")
        if v.type == "Real" and p.unit != v.unit:
            problems.append(f"{v.name}: unit {p.unit!r} (rumoca), {v.unit!r} (table)")
        if not (_same(p.min, v.lo) and _same(p.max, v.hi)):
            problems.append(f"{v.name}: range [{p.min}, {p.max}] (rumoca), [{v.lo}, {v.hi}] (table)")
    assert not problems, "\n".join(problems)
    assert list(m.inputs.names) == ["motor_torque"]


def _simulate_pulse_train(rumoca_session, t_end: float):
    rm, session = rumoca_session
    m = session.load(str(LIBRARY / "Examples" / "PulseTrain.mo"), model="HarmonicDrive.Examples.PulseTrain")
    r = m.simulate(t=(0.0, t_end), dt=1e-4, config=rm.SimConfig(rtol=1e-10, atol=1e-14))
    return r, m.parameters


def test_rumoca_pulse_train_example(rumoca_session):
    """The example runs: every pulse moves the arm forward, both bodies come to rest between pulses, nothing
    moves at rest, and the energy balances (input work = friction work + kinetic + spring energy)."""
    np = pytest.importorskip("numpy")
    r, params = _simulate_pulse_train(rumoca_session, 1.0)
    t = np.asarray(r.time)
    g = {n: np.asarray(r[f"plant.{n}"], dtype=float) for n in
         ("q_m", "q_l", "v_m", "v_l", "motor_stuck", "load_stuck", "input_work", "friction_work")}
    period = params["period"].value
    rests = np.searchsorted(t, [period * (k + 1) - 1e-3 for k in range(4)])
    assert np.all(g["motor_stuck"][rests] == 1) and np.all(g["load_stuck"][rests] == 1)
    assert np.all(g["v_m"][rests] == 0) and np.all(g["v_l"][rests] == 0)
    q_l = g["q_l"][rests]
    assert np.all(np.diff(np.concatenate([[0.0], q_l])) > 0), f"arm does not advance at every pulse: {q_l}"
    stuck = (g["motor_stuck"] == 1) & (g["load_stuck"] == 1) & (t > period - 1e-2) & (t < period)
    assert stuck.any() and np.ptp(g["q_l"][stuck]) == 0.0, "the arm creeps at rest"
    J_m, J_l, K_s, r_ = (TABLE[n].start for n in ("J_m", "J_l", "K_s", "r"))
    energy = (g["input_work"] - g["friction_work"] - 0.5 * J_m * g["v_m"] ** 2 - 0.5 * J_l * g["v_l"] ** 2
              - 0.5 * K_s * (r_ * g["q_m"] - g["q_l"]) ** 2)
    assert np.max(np.abs(energy)) < 1e-6 * g["input_work"][-1], np.max(np.abs(energy))


def test_rumoca_plant_agrees_with_fmu(rumoca_session, fmu2):
    """The Modelica twin driven by the example's pulse train (4 pulses of 2 f_m for 1 ms, every 0.25 s) ends each
    period where the FMU does: angles, stick states, encoder count and works."""
    np = pytest.importorskip("numpy")
    from fmpy import extract, instantiate_fmu, read_model_description

    r, params = _simulate_pulse_train(rumoca_session, 1.0)
    amplitude, width, period = (params[n].value for n in ("amplitude", "width", "period"))
    n_pulses = 4
    t = np.asarray(r.time)

    md = read_model_description(str(fmu2))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    unzipdir = extract(str(fmu2))
    fmu = instantiate_fmu(unzipdir, md, fmi_type="CoSimulation")
    f_m = TABLE["f_m"].start
    try:
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        time = 0.0
        for k in range(n_pulses):
            # the pulse, then rest until 1 ms before the next pulse (compare there), then the last 1 ms
            for torque, h in ((amplitude * f_m, width), (0.0, period - width - 1e-3)):
                fmu.setReal([vr["motor_torque"]], [torque])
                fmu.doStep(time, h)
                time += h
            i = int(np.argmin(np.abs(t - time)))
            reals = dict(zip(("q_m", "q_l", "input_work", "friction_work", "v_m", "v_l"),
                             fmu.getReal([vr[n] for n in ("q_m", "q_l", "input_work", "friction_work", "v_m", "v_l")])))
            stuck = fmu.getBoolean([vr["motor_stuck"], vr["load_stuck"]])
            count = fmu.getInteger([vr["encoder_count"]])[0]
            assert abs(t[i] - time) < 1e-9, (t[i], time)
            for name, value in reals.items():
                mine = float(np.asarray(r[f"plant.{name}"])[i])
                scale = max(abs(value), 1e-12 if name.startswith("v_") else 1e-15)
                assert abs(mine - value) <= 1e-5 * scale + (1e-12 if name.startswith("v_") else 0.0), \
                    f"pulse {k}: {name} = {mine!r} (Modelica, rumoca) vs {value!r} (FMU)"
            assert [bool(s) for s in stuck] == [True, True], f"pulse {k}: FMU not at rest"
            assert bool(np.asarray(r["plant.motor_stuck"])[i]) and bool(np.asarray(r["plant.load_stuck"])[i])
            assert int(np.asarray(r["plant.encoder_count"])[i]) == count, f"pulse {k}: encoder_count"
            fmu.doStep(time, 1e-3)
            time += 1e-3
    finally:
        fmu.terminate()
        fmu.freeInstance()
        shutil.rmtree(unzipdir, ignore_errors=True)


# ------------------------------------------------------------------------------ pymoca (an ANTLR grammar) --

@pytest.mark.parametrize("path", MO_FILES, ids=lambda p: str(p.relative_to(MODELICA_DIR)))
def test_pymoca_parses(path):
    parser = pytest.importorskip("pymoca.parser", reason="pymoca (Modelica grammar, PyPI 'pymoca') is not installed")
    tree = parser.parse(path.read_text(encoding="utf-8"))
    assert tree is not None, f"{path}: pymoca returned no tree"
