"""The claims of README.md and docs/*.md, checked against what the code computes.

Each test reads the claim from the document itself (a table, a path, an option, a number)
and compares it with the code's answer, so a document that drifts from the code fails here.
"""

from __future__ import annotations

import ast
import json
import re
import shutil
import subprocess
import sys
import tomllib
from importlib import metadata
from pathlib import Path

import pytest
from click.testing import CliRunner

from conftest import RIG
from fdigen.cli import main as cli_main

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
DOCS = {p.name: p.read_text() for p in sorted((ROOT / "docs").glob("*.md"))
        if p.name != "reliability.md"}  # reliability.md is generated
PKG = ROOT / "src" / "fdigen"


def _section(text: str, title: str) -> str:
    """The text of a ``## title`` section, up to the next ``## ``."""
    start = text.index(f"## {title}")
    nxt = text.find("\n## ", start + 3)
    return text[start:] if nxt < 0 else text[start:nxt]


def _table(text: str, header_start: str) -> list[list[str]]:
    """Rows (cells stripped) of the markdown table whose header line starts with
    ``header_start``."""
    lines = text.splitlines()
    i = next(k for k, line in enumerate(lines) if line.startswith(header_start))
    rows = []
    for line in lines[i + 2:]:
        if not line.startswith("|"):
            break
        rows.append([c.strip() for c in re.split(r"(?<!\\)\|", line.strip())[1:-1]])
    return rows


# -- the first commands and the environment -------------------------------------------

def test_ci_runs_the_readme_test_command():
    first = README.split("```bash\n", 1)[1].split("```", 1)[0]
    commands = [line.split("#")[0].strip() for line in first.splitlines()]
    assert "./scripts/setup && .venv/bin/fdigen build" in commands
    assert "./scripts/setup && .venv/bin/python -m pytest -q" in commands
    ci = (ROOT / ".ci" / "run").read_text()
    assert "./scripts/setup && .venv/bin/python -m pytest -q" in ci


def test_setup_reinstalls_when_pyproject_changes():
    setup = (ROOT / "scripts" / "setup").read_text()
    assert "sha256sum pyproject.toml" in setup
    assert re.search(r"pip install .*-e '\.\[test\]'", setup)


def _imports(folder: Path) -> set[str]:
    names = set()
    for path in folder.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names |= {a.name.split(".")[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names.add(node.module.split(".")[0])
    return names - set(sys.stdlib_module_names)


def _norm(name: str) -> str:
    return name.lower().replace("_", "-")


def _requirement_names(reqs) -> set[str]:
    """Distribution names a list of requirements installs, with those of their extras
    (``dask[distributed]`` brings ``distributed``)."""
    names = set()
    for req in reqs:
        m = re.match(r"([\w.-]+)(?:\[([\w,\s-]+)\])?", req)
        names.add(_norm(m.group(1)))
        for extra in (m.group(2) or "").split(","):
            if not extra.strip():
                continue
            for sub in metadata.requires(m.group(1)) or []:
                if re.search(rf"extra\s*==\s*[\"']{extra.strip()}[\"']", sub):
                    names.add(_norm(re.match(r"[\w.-]+", sub).group(0)))
    return names


def _distributions(module: str) -> set[str]:
    return {d.lower().replace("_", "-")
            for d in metadata.packages_distributions().get(module, [])}


def test_pyproject_declares_every_import():
    """A fresh `pip install -e '.[test]'` (scripts/setup) gets every module fdigen and its
    tests import: each third-party import is provided by a declared distribution."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    runtime = _requirement_names(project["dependencies"])
    test = runtime | _requirement_names(project["optional-dependencies"]["test"])
    local = {"fdigen", "conftest", "reliability_log"} | {p.stem for p in
                                                        (ROOT / "tests").glob("*.py")} \
        | {p.parent.name for p in (ROOT / "tests").glob("*/__init__.py")}
    for folder, declared in ((PKG, runtime), (ROOT / "tests", test)):
        for module in sorted(_imports(folder) - local):
            if module == "setuptools":  # comes with every venv (test_package skips otherwise)
                continue
            dists = _distributions(module)
            assert dists, f"{module} imported in {folder.name} but not installed"
            assert dists & declared, f"{module} ({dists}) imported in {folder.name}/ " \
                                     f"is not in pyproject.toml's dependencies"


# -- paths and modules named in the documents -----------------------------------------

def test_layout_block_names_real_files():
    """Every folder and file of the README's Layout block exists, and every subpackage of
    src/fdigen is in it."""
    block = _section(README, "Layout").split("```\n", 1)[1].split("```", 1)[0]
    folder = PKG
    listed = set()
    for line in block.splitlines():
        head = re.match(r"(\s*)([A-Za-z_]+/)(\s|$)", line)
        if line.startswith("src/fdigen/"):
            continue
        if head and not head.group(1):
            top = ROOT / head.group(2)
            assert top.is_dir(), f"Layout names {head.group(2)}, which does not exist"
            folder = None
            continue
        if head and head.group(1) == "  ":
            folder = PKG / head.group(2)
            listed.add(head.group(2).rstrip("/"))
            assert folder.is_dir(), f"Layout names src/fdigen/{head.group(2)}"
        elif not line.startswith(" "):
            folder = PKG if line.split()[0].endswith(".py") else None
        if folder is None:
            continue
        for name in re.findall(r"\b([a-z_]+\.py)\b", line):
            assert (folder / name).is_file() or (PKG / name).is_file(), \
                f"Layout names {name} under {folder.relative_to(ROOT)}"
        for sub in re.findall(r"\b([a-z_]+)/ \(", line):
            assert (folder / sub).is_dir(), f"Layout names {sub}/ under {folder}"
    subpackages = {p.parent.name for p in PKG.glob("*/__init__.py")}
    assert subpackages <= listed, f"not in the Layout block: {sorted(subpackages - listed)}"


_ROOTS = ("src/", "tests/", "docs/", "scripts/", "templates/", "generated/", "examples/",
          "bench/", ".ci/", "fdigen/")
_PATH = re.compile(r"`([\w./-]+)`")


def _resolve(token: str) -> bool:
    """Whether a path named in a document exists: from the repository root, from
    src/ or src/fdigen/, or (a bare file name) anywhere under src/fdigen/ or tests/."""
    token = token.rstrip("/")
    if any((base / token).exists() for base in (ROOT, ROOT / "src", PKG, PKG / "models")):
        return True
    return "/" not in token and any(PKG.rglob(token)) or any((ROOT / "tests").glob(token))


@pytest.mark.parametrize("doc", ["README.md", *DOCS])
def test_named_paths_exist(doc):
    """Every source, test, script or document path a document names in backticks exists
    (files that commands write, and the generated files listed per model, are tested
    elsewhere)."""
    text = README if doc == "README.md" else DOCS[doc]
    missing = []
    for token in sorted(set(_PATH.findall(text))):
        is_path = token.startswith(_ROOTS) or re.fullmatch(
            r"([a-z_]+/)*[a-z_]+\.(py|toml|md)|([a-z_]+/)+", token)
        if not is_path or token.endswith(("EXPERIMENTS.md", "results.json")):
            continue
        if token.startswith(("generated/",)) and token.count("/") > 2:
            continue
        if not _resolve(token):
            missing.append(token)
    assert not missing, f"{doc} names paths that do not exist: {missing}"


@pytest.mark.parametrize("doc", ["README.md", *DOCS])
def test_named_modules_exist(doc):
    """`fdigen.x.y` names in a document are importable modules (or their attributes)."""
    import importlib

    text = README if doc == "README.md" else DOCS[doc]
    for dotted in sorted(set(re.findall(r"`(fdigen(?:\.[a-z_]+)+)`", text))):
        parts = dotted.split(".")
        for k in range(len(parts), 0, -1):
            try:
                obj = importlib.import_module(".".join(parts[:k]))
            except ImportError:
                continue
            for attr in parts[k:]:
                obj = getattr(obj, attr)
            break
        else:
            pytest.fail(f"{doc} names {dotted}, which does not exist")


# -- commands ------------------------------------------------------------------------

def _help(args) -> str:
    result = CliRunner().invoke(cli_main, [*args, "--help"], terminal_width=200)
    assert result.exit_code == 0, (args, result.output)
    return result.output


def test_commands_table_options_exist():
    """Every command of the README's Commands table exists, with every option it shows."""
    rows = _table(_section(README, "Commands"), "| command |")
    assert rows
    for row in rows:
        for usage in re.findall(r"`(fdigen [^`]+)`", row[0]):
            words = usage.split()[1:]
            cmd = [words[0]]
            if words[0] == "platform":
                cmd.append(words[1].split("/")[0])
            text = _help(cmd)
            for option in re.findall(r"(?<![\w-])(--?[a-z][a-z-]*)", usage):
                assert re.search(rf"(?<![\w-]){re.escape(option)}\b", text), \
                    f"`{usage}`: {option} not in `fdigen {' '.join(cmd)} --help`"
        for sub in re.findall(r"`fdigen platform ([a-z/]+)", row[1]):
            for name in sub.split("/"):
                _help(["platform", name])


def test_every_command_is_in_the_table():
    """Every command is in the table, and every one but `platform ik` takes --model."""
    section = _section(README, "Commands")
    assert "Every command but `platform ik` takes `--model NAME|FILE`" in section
    for name, command in cli_main.commands.items():
        assert f"`fdigen {name}" in section, f"fdigen {name} is not in the Commands table"
        subcommands = getattr(command, "commands", None)
        for args in ([[name, sub] for sub in subcommands] if subcommands else [[name]]):
            if args[-1] == "ik":
                continue
            assert "--model" in _help(args), args


# -- the model file format -----------------------------------------------------------

def _readme_model_block() -> dict[str, set[str]]:
    """{table: keys} of the README's model-file sketch."""
    block = _section(README, "Writing a model").split("```toml\n", 1)[1].split("```", 1)[0]
    keys: dict[str, set[str]] = {}
    table = None
    for line in block.splitlines():
        line = line.split("#")[0]
        m = re.match(r"\[([\w.]+)\]\s*(.*)", line)
        if m:
            table, rest = m.group(1), m.group(2)
        else:
            rest = line
        if table is None:
            continue
        inner = re.findall(r"\{(.*)\}", rest)
        found = re.findall(r"\b([a-z_]+)\s*=", inner[0] if inner else rest)
        if table in ("model", "fdi"):
            found = [w for w in re.findall(r"\b([a-z_]+)\b", rest)]
        keys.setdefault(table, set()).update(found)
    return keys


def _refused_keys(table: str) -> set[str]:
    """The keys the model reader allows in ``table`` (read from its refusal of an
    unknown key, which lists them)."""
    import tomlkit

    from fdigen.errors import FdigenError
    from fdigen.model.model_file import builtin_model_path, load_model

    name = "three_tank" if table in ("faults", "simulation.controllers") else \
        "pneumatic_cylinder"
    doc = tomlkit.parse(builtin_model_path(name).read_text())
    path = table.split(".")
    node = doc
    for key in path:
        node = node[key]
    if path[0] in ("parameters", "states", "inputs", "outputs", "faults") or \
            path[-1] in ("kalman", "controllers"):
        node = node[next(iter(node))]
    node["zz_undocumented"] = 1
    from tempfile import TemporaryDirectory

    with TemporaryDirectory() as tmp:
        file = Path(tmp) / "m.toml"
        file.write_text(tomlkit.dumps(doc))
        with pytest.raises(FdigenError, match="unknown key") as info:
            model = load_model(str(file))
            if table.startswith("fdi"):  # [fdi] is read with the design's settings
                from fdigen.design.config import read_fdi_config

                read_fdi_config(model)
    allowed = re.search(r"allowed: ([\w, ]+)", str(info.value)).group(1)
    return {k.strip() for k in allowed.split(",")}


@pytest.mark.parametrize("table,readme_table", [
    ("model", "model"), ("parameters", "parameters"), ("states", "states"),
    ("inputs", "inputs"), ("outputs", "outputs"), ("faults", "faults.leak_p"),
    ("fdi", "fdi"), ("fdi.kalman", "fdi.kalman.R4"), ("simulation", "simulation"),
    ("simulation.controllers", "simulation.controllers.level1")])
def test_model_file_keys(table, readme_table):
    """Every key the README's model-file sketch shows is accepted; an undocumented key is
    refused; every accepted key is named somewhere in the README."""
    documented = _readme_model_block()[readme_table]
    if readme_table == "faults.leak_p":
        documented |= _readme_model_block()["faults.clog12"]
        documented -= {"target"} - documented  # `target` is inside `terms` too
    allowed = _refused_keys(table)
    assert documented - {"term", "target"} <= allowed | {"term", "target"}, \
        f"[{readme_table}] documents {sorted(documented - allowed)}, which are refused"
    undocumented = {k for k in allowed if f"`{k}`" not in README and
                    not re.search(rf"\b{k}\s*=", README) and k not in documented}
    assert not undocumented, f"[{table}] accepts keys the README never names: " \
                             f"{sorted(undocumented)}"


def test_expression_limits():
    """'exponents beyond ±64, expressions nested deeper than 60 levels or longer than 4000
    characters are refused'."""
    from fdigen.errors import FdigenError
    from fdigen.model import expression

    m = re.search(r"exponents beyond ±(\d+), expressions nested deeper than (\d+)\s+levels,"
                  r"\s+longer than (\d+) characters or of more than (\d+) nodes", README)
    exp, depth, length, nodes = (int(g) for g in m.groups())
    assert (expression.MAX_EXPONENT, expression.MAX_DEPTH, expression.MAX_LENGTH,
            expression.MAX_NODES) == (exp, depth, length, nodes)
    import sympy as sp

    x = sp.Symbol("x")
    parse = expression.parse_expression
    sig = __import__("inspect").signature(parse)
    kwargs = {}
    if "field" in sig.parameters:
        kwargs["field"] = "f"
    parse(f"x**{exp}", {"x": x}, **kwargs)
    parse("-" * (depth - 1) + "x", {"x": x}, **kwargs)
    for bad in (f"x**{exp + 1}", "-" * (depth + 1) + "x", "1" * (length + 1),
                "x" + "+x" * (nodes // 2)):
        with pytest.raises(FdigenError):
            parse(bad, {"x": x}, **kwargs)


# -- results on the rig logs ---------------------------------------------------------

def test_rig_log_results_table():
    """The README's table of `fdigen detect` on the seven fdi_* rig logs is what the tuned
    compiled core gives: class, action, isolation time, consistent faults and their time,
    fault onset from the log's ground truth."""
    logs = RIG / "logs"
    if not (logs / "fdi_healthy.csv").is_file():
        pytest.skip(f"rig logs not available in {logs}")
    from fdigen.design.cache import cached_design
    from fdigen.detect import detect_log
    from fdigen.model.model_file import load_model

    design = cached_design(load_model())
    section = _section(README, "Results on the reference rig logs")
    assert "`fdigen detect LOG` on each `../shared/rig/logs/fdi_*.csv`" in section
    assert [p.name for p in cli_main.commands["detect"].params if p.nargs != 1] == []
    rows = _table(section, "| log |")
    assert sorted(r[0] for r in rows) == sorted(p.stem for p in logs.glob("fdi_*.csv"))
    assert len(rows) == 7  # "the seven `fdi_*` rig logs"
    for name, diagnosis, action, isolated in rows:
        summary, _ = detect_log(design, logs / f"{name}.csv")
        assert summary["backend"] == "CFdi"  # "compiled core"
        d = summary["diagnosis"]
        assert diagnosis.split(";")[0] == d["fault"], name
        assert action == d["action"], name
        if d["t_isolated"] is None:
            assert isolated == "–", name
            assert not summary["flags"], name
            continue
        m = re.fullmatch(r"([\d.]+) \(([\d.]+)\)", isolated)
        assert float(m.group(1)) == pytest.approx(d["t_isolated"], abs=5e-4), name
        truth = json.loads((logs / f"{name}.json").read_text())["truth"]["faults"]
        assert float(m.group(2)) == truth[0]["t0"], name
        consistent = re.search(r"consistent: `([^`]+)`(?: from ([\d.]+))?", diagnosis)
        if consistent:
            assert consistent.group(1) == d["fault_set"], name
            if consistent.group(2):
                assert float(consistent.group(2)) == pytest.approx(d["t_fault_set"],
                                                                   abs=5e-4), name
        raised = {f["residual"] for f in summary["flags"]}
        said = re.search(r"\(([^)]*) raised, ([^)]*) low\)", diagnosis)
        if said:
            assert set(re.findall(r"R\d+", said.group(1))) <= raised, name
            assert not set(re.findall(r"R\d+", said.group(2))) & raised, name
    summary, _ = detect_log(design, logs / "discrepancy_none.csv")
    assert "`discrepancy_none` log (Ff and K off the datasheet) raises no flag" in README
    assert not summary["flags"]


# -- derived tables --------------------------------------------------------------------

def _design_json(model: str) -> dict:
    return json.loads((ROOT / "generated" / model / "design.json").read_text())


def test_isolability_table_is_the_derived_one():
    table = _table(README, "| isolable from → |")
    short = {"block_p": "blockage_p", "block_n": "blockage_n", "x3": "position_sensor",
             "x2": "redundant_position_sensor", "pp": "pressure_sensor_p",
             "pn": "pressure_sensor_n"}
    iso = _design_json("pneumatic_cylinder")["isolability"]
    faults = iso["faults"]
    for row in table:
        i = faults.index(short.get(row[0], row[0]))
        for j, cell in enumerate(row[1:]):
            if i == j:
                continue
            for key in ("achieved", "achievable"):
                assert (cell == "✓") == bool(iso[key][i][j]), (row[0], faults[j], key)


@pytest.mark.parametrize("model,header", [("three_tank", "| fault | class | R1 |"),
                                          ("heat_exchanger", "| fault | class | Rh |")])
def test_models_doc_signature_tables(model, header):
    """docs/models.md's signature tables are the committed designs' (which `fdigen build
    --check` keeps equal to the derived ones)."""
    text = DOCS["models.md"]
    lines = text.splitlines()
    columns = [c.strip() for c in next(l for l in lines if l.startswith(header))
               .strip("|").split("|")]
    design = _design_json(model)
    classes = {}
    for spec in design["faults"] if isinstance(design["faults"], list) else []:
        if isinstance(spec, dict):
            classes[spec.get("name")] = spec.get("class")
    for row in _table(text, header):
        fault = row[0]
        for residual, cell in zip(columns[2:], row[2:]):
            assert int(cell) == design["signature_table"][residual][fault], \
                (model, fault, residual)
        if classes.get(fault):
            assert row[1] == classes[fault], (model, fault)


def test_models_doc_overview():
    """'fdigen ships four model files'; states, controlled inputs and faults per model."""
    from fdigen.model.model_file import BUILTIN_MODELS, load_model

    text = DOCS["models.md"]
    assert "ships four model files" in text and len(BUILTIN_MODELS) == 4
    rows = _table(text, "| model | physics |")
    assert {r[0].strip("`") for r in rows} == set(BUILTIN_MODELS)
    for name, _, states, inputs, faults, generated in rows:
        model = load_model(name.strip("`"))
        assert int(states) == len(model.states), name
        assert int(inputs.split()[0]) == len(model.inputs), name
        assert int(faults) == len(model.faults), name
        assert (ROOT / generated.strip("`")).is_dir(), name


# -- generated code --------------------------------------------------------------------

def test_generated_files_table():
    """The files the README lists under 'Generated code' exist for every built-in model."""
    from fdigen.model.model_file import BUILTIN_MODELS

    rows = _table(_section(README, "Generated code and its proof"), "| file |")
    for model in BUILTIN_MODELS:
        out = ROOT / "generated" / model
        for row in rows:
            for token in re.findall(r"`([^`]+)`", row[0]):
                token = token.replace("pneumatic_cylinder", model).rstrip("…")
                names = [token]
                brace = re.search(r"\{([^}]+)\}", token)
                if brace:
                    names = [token.replace(brace.group(0), e)
                             for e in brace.group(1).split(",")]
                for name in names:
                    assert (out / name).exists(), f"generated/{model}/{name}"


def test_state_struct_window_claim():
    """'The state struct (caller-owned) holds the RMS windows: WINDOW × NR floats'."""
    header = (ROOT / "generated/pneumatic_cylinder/c_float/pneumatic_cylinder_fdi.h") \
        .read_text()
    window = int(re.search(r"#define PNEUMATIC_CYLINDER_FDI_WINDOW (\d+)", header).group(1))
    nr = int(re.search(r"#define PNEUMATIC_CYLINDER_FDI_NR (\d+)", header).group(1))
    m = re.search(r"holds the\s+RMS windows: (\d+) × (\d+) floats", README)
    assert (int(m.group(1)), int(m.group(2))) == (window, nr)


def test_cortex_m4_figures(tmp_path):
    """README's Cortex-M4F figures (.text, stack from _step, state struct) are within 5 %
    of what arm-none-eabi-gcc gives today (the exact numbers move with the design)."""
    gcc = shutil.which("arm-none-eabi-gcc")
    size = shutil.which("arm-none-eabi-size")
    if not gcc or not size:
        pytest.skip("arm-none-eabi-gcc not installed (scripts/setup installs it as root)")
    src = ROOT / "generated/pneumatic_cylinder/c_float"
    flags = ["-mcpu=cortex-m4", "-mthumb", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard", "-Os",
             "-std=c99", "-ffunction-sections", "-fdata-sections", "-fno-common",
             "-fstack-usage", f"-I{src}"]
    (tmp_path / "probe.c").write_text('#include "pneumatic_cylinder_fdi.h"\nunsigned char '
                                      "probe[sizeof(pneumatic_cylinder_fdi_state)];\n")
    for name, c in (("fdi", src / "pneumatic_cylinder_fdi.c"), ("probe", tmp_path / "probe.c")):
        subprocess.run([gcc, *flags, "-c", str(c), "-o", str(tmp_path / f"{name}.o")],
                       check=True, cwd=tmp_path)
    sections = {}
    for name in ("fdi", "probe"):
        out = subprocess.run([size, "-A", str(tmp_path / f"{name}.o")], check=True,
                             capture_output=True, text=True).stdout
        for line in out.splitlines():
            parts = line.split()
            if len(parts) == 3 and parts[1].isdigit():
                sections[parts[0]] = int(parts[1])
    text = sum(v for k, v in sections.items() if k.startswith(".text"))
    data = sum(v for k, v in sections.items() if k.startswith((".data", ".bss"))
               and "probe" not in k)
    state = sections[".bss.probe"]
    stack = {}
    for line in (tmp_path / "fdi.su").read_text().splitlines():
        fn, used = line.split("\t")[0].rsplit(":", 1)[-1], int(line.split("\t")[1])
        stack[fn] = used
    worst = stack["pneumatic_cylinder_fdi_step"] + max(
        v for k, v in stack.items() if k.startswith("pneumatic_cylinder_fdi_residuals"))
    m = re.search(r"`\.text` ([\d,]+) bytes, `\.data` and `\.bss` 0; worst stack path\s+"
                  r"from `_step` (\d+) bytes.*?state struct \(caller-owned, ([\d,]+) B\)",
                  README, re.S)
    claimed = [int(g.replace(",", "")) for g in m.groups()]
    assert data == 0
    for what, got, said in zip((".text", "stack", "state"), (text, worst, state), claimed):
        assert abs(got - said) <= 0.05 * said, f"{what}: measured {got}, README says {said}"


def test_isolation_doc_structural_table():
    """docs/isolation.md: MSO counts, the ordered pairs no residual can separate and the
    extra sensor that would, per model (also in the README: 4 pairs and 2 pairs)."""
    text = DOCS["isolation.md"]
    m = re.search(r"MSO sets \((\d+) for the cylinder, (\d+) for the\s+motor\)", text)
    for model, count in zip(("pneumatic_cylinder", "dc_motor"), m.groups()):
        assert len(_design_json(model)["isolability"]["mso_sets"]) == int(count), model
    for model, pairs, which, sensor in _table(text, "| model | ordered pairs not"):
        iso = _design_json(model)["isolability"]
        achievable = {tuple(p) for p in iso["achievable_non_isolable"]}
        assert len(achievable) == int(pairs), model
        assert {tuple(p) for p in iso["achieved_non_isolable"]} == achievable, model
        for a, b in re.findall(r"(\w+)/(\w+)", which):
            assert {(a, b), (b, a)} <= achievable, (model, a, b)
        placed = {s for p in iso["sensor_placement"] for s in p["sensors"]}
        named = set(re.findall(r"`(\w+)`", sensor))
        assert placed == named, (model, placed, sensor)
    assert re.search(r"for the cylinder only a leak and a blockage of the\s+\*same\* line "
                     r"\(4 ordered pairs\); for the DC motor drive and winding \(2\)", README)


def _detection_rows(section_title: str):
    text = _section(DOCS["models.md"], section_title)
    return _table(text, "| log | flags")


@pytest.mark.parametrize("model,t0,duration", [("three_tank", 250, 600),
                                               ("heat_exchanger", 500, 1200)])
def test_models_doc_detection_tables(model, t0, duration, tmp_path):
    """docs/models.md's detection tables: `fdigen simulate --model M --fault NAME@T0=SIZE`
    (seed 0) then `fdigen detect --json` give those flags, times and diagnoses."""
    section = _section(DOCS["models.md"], model)
    assert f"{duration} s" in section and str(t0) in section
    for log, flags, diagnosis in _detection_rows(model):
        args = ["simulate", "--model", model, "--duration", str(duration), "--seed", "0",
                "-o", str(tmp_path / "run.csv")]
        if log != "healthy":
            name, size = re.fullmatch(r"(\w+) = ([\d.]+).*", log).groups()
            args += ["--fault", f"{name}@{t0}={size}"]
        result = CliRunner().invoke(cli_main, args)
        assert result.exit_code == 0, result.output
        result = CliRunner().invoke(cli_main, ["detect", "--model", model, "--json",
                                               str(tmp_path / "run.csv")])
        assert result.exit_code == 0, result.output
        summary = json.loads(result.output)
        raised = {f["residual"]: f["t_raised"] for f in summary["flags"]}
        said = {} if flags == "none" else {
            r: float(v) for r, v in re.findall(r"(\w+) ([\d.]+)", flags)}
        assert set(raised) == set(said), (model, log, raised)
        for r, v in said.items():
            assert raised[r] == pytest.approx(v, abs=0.051), (model, log, r)
        d = summary["diagnosis"]
        if diagnosis.startswith(("none", "not isolated")):
            assert d["t_isolated"] is None, (model, log, d)
            continue
        cls, when = re.match(r"(\w+) at ([\d.]+) s", diagnosis).groups()
        assert d["fault"] == cls and d["t_isolated"] == pytest.approx(float(when), abs=0.051)
        action = re.search(r", (\w+)$", diagnosis)
        if action:
            assert d["action"] == action.group(1), (model, log)


def test_r7_levels_on_rig_logs():
    """'on the rig's actuator-loss log its RMS stays at its healthy level (0.08) while a
    leak drives it to 32 and a blockage to 51'."""
    logs = RIG / "logs"
    if not (logs / "fdi_healthy.csv").is_file():
        pytest.skip(f"rig logs not available in {logs}")
    import numpy as np

    from fdigen.design.cache import cached_design
    from fdigen.detect import detect_log
    from fdigen.model.model_file import load_model

    m = re.search(r"its RMS\s+stays at its healthy level \(([\d.]+)\) while a leak drives it "
                  r"to (\d+) and a blockage to (\d+)", README)
    healthy, leak, blockage = (float(g) for g in m.groups())
    design = cached_design(load_model())
    k = design.evaluation.residuals.index("R7")
    peak = {name: float(np.max(np.asarray(detect_log(design, logs / f"{name}.csv")[1]["rms"])
                               [:, k]))
            for name in ("fdi_healthy", "fdi_actuator_loss", "fdi_leak_p", "fdi_blockage_p")}
    assert peak["fdi_healthy"] == pytest.approx(healthy, abs=0.005)
    assert peak["fdi_actuator_loss"] < 1.25 * peak["fdi_healthy"]
    assert peak["fdi_leak_p"] == pytest.approx(leak, rel=0.05)
    assert peak["fdi_blockage_p"] == pytest.approx(blockage, rel=0.05)


def test_discover_stiffness_of_sign_flows():
    """docs/models.md: `fdigen discover` writes the three-tank augmented model. Its RK4
    check takes the Jacobian of the Torricelli flows' `sign`, whose derivative is
    `2 DiracDelta` (0 almost everywhere), not a NameError."""
    from types import SimpleNamespace

    import numpy as np

    from fdigen.discover.augment import stiffness
    from fdigen.model.model_file import load_model

    model = load_model("three_tank")
    data = SimpleNamespace(xs=np.array([[0.45, 0.3, 0.2], [0.5, 0.35, 0.25]]),
                           u=np.full((2, len(model.inputs)), 5e-5))
    lam = stiffness(model, data)
    assert np.isfinite(lam) and lam > 0


def test_threshold_design_paragraph():
    """'**Thresholds**: `fdigen tune` ran 40 healthy closed-loop runs with ... ±10 % ...
    1 % false alarms per run (×1.25 margin); the voter thresholds are kept at 0.5' are
    tune's defaults and the committed design."""
    m = re.search(r"`fdigen tune` ran (\d+) healthy closed-loop runs\s+with the friction and "
                  r"valve constant spread ±(\d+) %.*?threshold for (\d+) % false alarms per "
                  r"run \(×([\d.]+) margin\); the voter thresholds are kept at\s+([\d.]+)",
                  README, re.S)
    runs, spread, rate, margin, voter = m.groups()
    defaults = {p.name: p.default for p in cli_main.commands["tune"].params}
    assert defaults["runs"] == int(runs)
    assert defaults["tolerance"] == pytest.approx(int(spread) / 100)
    assert defaults["false_alarm_rate"] == pytest.approx(int(rate) / 100)
    assert defaults["margin"] == pytest.approx(float(margin))
    thresholds = _design_json("pneumatic_cylinder")["isolation"]["thresholds"]
    assert {thresholds[w] for w in ("w1", "w2", "w3")} == {float(voter)}
    uncertain = {q for q, spec in tomllib.loads(
        (PKG / "models" / "pneumatic_cylinder.toml").read_text())["parameters"].items()
        if spec.get("uncertain")}
    assert uncertain == {"Ff", "K"}  # friction and valve constant


def test_equivalence_tolerances():
    """'Tolerances asserted: 1e-12 on points, 1e-9 on trajectories', on 1000 points."""
    from fdigen.verify import equivalence

    m = re.search(r"Tolerances asserted: ([\de.-]+) on points, ([\de.-]+) on\s+trajectories",
                  README)
    assert (equivalence.POINT_RTOL, equivalence.TRAJECTORY_RTOL) == tuple(
        float(g) for g in m.groups())
    assert "on\n1000 seeded random points" in README or "1000 seeded random points" in README
    defaults = {p.name: p.default for p in cli_main.commands["verify"].params}
    assert defaults["points"] == 1000


def _command_and_options(span: str):
    """(command path, options) of an inline `fdigen ...` usage."""
    words = span.split()
    if len(words) < 2 or words[1] not in cli_main.commands:
        return None, []
    path = [words[1]]
    group = cli_main.commands[words[1]]
    if getattr(group, "commands", None) and len(words) > 2:
        sub = words[2].split("/")[0]
        if sub in group.commands:
            path.append(sub)
    return path, re.findall(r"(?<![\w-])(--[a-z][a-z-]*)", span)


@pytest.mark.parametrize("doc", ["README.md", *DOCS])
def test_inline_commands_have_their_options(doc):
    """Every inline `fdigen CMD ... --option` in a document names a real command and
    options that command accepts."""
    text = README if doc == "README.md" else DOCS[doc]
    helps = {}
    bad = []
    code = "\n".join(re.findall(r"```\w*\n(.*?)```", text, re.S))
    blocks = re.findall(r"^(fdigen [a-z]+ .*)$", re.sub(r"\n\s+", " ", code), re.M)
    for span in re.findall(r"`(fdigen [^`]+)`", text.replace("\n", " ")) + blocks:
        path, options = _command_and_options(span)
        if path is None:
            if re.match(r"fdigen [a-z]+\b", span):
                bad.append(f"{span}: no such command")
            continue
        key = " ".join(path)
        helps.setdefault(key, _help(path))
        bad += [f"{span}: {o}" for o in options
                if not re.search(rf"(?<![\w-]){re.escape(o)}\b", helps[key])]
        command = cli_main.commands[path[0]]
        command = command.commands[path[1]] if len(path) > 1 else command
        defaults = {o: p.default for p in command.params for o in getattr(p, "opts", [])}
        for option, value in re.findall(r"\[(--[a-z-]+) (\d[\d.e+-]*)\]", span):
            if option in defaults and float(value) != defaults[option]:
                bad.append(f"{span}: {option} shown as {value}, default {defaults[option]}")
    assert not bad, f"{doc}: {bad}"


def test_discover_json_example(tmp_path):
    """docs/discover.md's `--json` example is what `fdigen discover` gives on the rig's
    `discrepancy_coulomb` log (to the digits shown), with the keys the document lists."""
    log = RIG / "logs" / "discrepancy_coulomb.csv"
    if not log.is_file():
        pytest.skip(f"rig log {log} not available")
    text = DOCS["discover.md"]
    example = json.loads(re.search(r"```json\n(.*?)```", text, re.S).group(1))
    result = CliRunner().invoke(cli_main, ["discover", str(log), "--no-build", "--no-fdi",
                                           "--json", "--out", str(tmp_path / "out")])
    assert result.exit_code == 0, result.output
    got = json.loads(result.output)

    _same_to_digits(example, got, "discover")
    listed = re.search(r"plus (`uncertainty`.*?)and the file paths", text, re.S).group(1)
    for key in re.findall(r"`(\w+)(?:/after)?`", listed):
        if key.startswith("fdi_"):
            continue  # --no-fdi
        if key.endswith("_before"):
            assert key in got and key.replace("_before", "_after") in got, key
        else:
            assert key in got, key


def test_extra_residuals_as_described():
    """README 'Beyond the paper': R6 is `x, xdot` driven by `pp, pn` checked on `x3`; R7 is
    blind to the valve; R8 is `Pp, x, xdot` driven by `pn` checked on `x3`, R9 the
    mirror. Their signatures: R6 not leaks or the valve; R8 not line n."""
    extra = {e["residual"]: e for e in _design_json("pneumatic_cylinder")["extra_residuals"]}
    assert set(extra) == {"R6", "R7", "R8", "R9"}
    r6 = re.search(r"\(`R6`: equations `([^`]+)`, drivers `([^`]+)`, checked on `(\w+)`\)",
                   README.replace("\n  ", " "))
    assert extra["R6"]["equations"] == r6.group(1).split(", ")
    assert sorted(extra["R6"]["drivers"].values()) == sorted(r6.group(2).split(", "))
    assert extra["R6"]["check"] == r6.group(3)
    assert extra["R7"]["blind_to"] == "valve"
    r8 = re.search(r"`R8`, \*line p\*: chamber p and the piston's motion \(`([^`]+)`\) driven "
                   r"by the measured\s+`(\w+)`, checked on the position `(\w+)`", README)
    assert extra["R8"]["equations"] == r8.group(1).split(", ")
    assert list(extra["R8"]["drivers"].values()) == [r8.group(2)]
    assert extra["R8"]["check"] == extra["R9"]["check"] == r8.group(3)
    assert extra["R9"]["equations"] == ["Pn", "x", "xdot"]
    sig = _design_json("pneumatic_cylinder")["signature_table"]
    assert not any(sig["R6"][f] for f in ("leak_p", "leak_n", "blockage_p", "blockage_n",
                                           "valve"))
    assert all(sig["R8"][f] for f in ("valve", "leak_p", "blockage_p"))
    assert not any(sig["R8"][f] for f in ("leak_n", "blockage_n"))
    assert all(sig["R9"][f] for f in ("valve", "leak_n", "blockage_n"))


def test_generated_c_api_and_includes():
    """The generated C's functions and error codes named in the README exist, and it
    includes only the headers the README lists (no stdio, no malloc)."""
    listed = re.search(r"no stdio, only\s+(.*?), and compiles", README, re.S).group(1)
    allowed = set(re.findall(r"`<([\w.]+)>`", listed))
    for model in ("pneumatic_cylinder", "three_tank"):
        for variant in ("c", "c_float"):
            header = (ROOT / "generated" / model / variant / f"{model}_fdi.h").read_text()
            source = (ROOT / "generated" / model / variant / f"{model}_fdi.c").read_text()
            for fn in ("default_params", "check_params", "init", "reset", "step", "core",
                       "run"):
                assert re.search(rf"\b{model}_fdi_{fn}\(", header), (model, fn)
            assert f"{model.upper()}_FDI_ERR_PARAM(" in header
            assert f"{model.upper()}_FDI_ERR_STATE" in header
            includes = set(re.findall(r"#include <([^>]+)>", header + source))
            assert includes <= allowed, (model, includes - allowed)
            assert not re.search(r"\b(malloc|calloc|free|printf)\s*\(", source)


def test_riccati_refinement_steps(monkeypatch):
    """docs/reproducibility.md: Newton's refinement takes 'three to four steps for each of
    the cylinder's 12 Riccati equations' (from SciPy's start), with `n ≤ 6`."""
    from fdigen.derive import riccati
    from fdigen.design.fdi_design import fdi_design
    from fdigen.model.model_file import load_model

    m = re.search(r"\): (\w+) to (\w+) steps for each\s+of the cylinder's (\d+) Riccati "
                  r"equations", DOCS["reproducibility.md"])
    words = {"two": 2, "three": 3, "four": 4, "five": 5, "six": 6}
    seen = []
    original = riccati.refine

    def counting(A, C, Q, R, P0, discrete):
        out = original(A, C, Q, R, P0, discrete)
        seen.append((discrete, len(A), out["steps"]))
        return out

    monkeypatch.setattr(riccati, "refine", counting)
    fdi_design(load_model())
    steps = {s for _, _, s in seen}
    assert len(seen) == int(m.group(3)), seen
    assert min(steps) == words[m.group(1)] and max(steps) == words[m.group(2)], seen
    assert max(n for _, n, _ in seen) <= 6


def test_realignment_gains_exactly_opposite():
    """docs/reproducibility.md: the chamber pressures' realignment gains 'now come out
    exactly opposite (`∓1946.9931448258812`)' in the committed design."""
    m = re.search(r"exactly opposite \(`∓([\d.]+)`\)", DOCS["reproducibility.md"])
    gain = _design_json("pneumatic_cylinder")["realignment_gain"]
    assert gain[0][0] == -float(m.group(1)) and gain[1][0] == float(m.group(1))


def test_isolation_doc_pairs_before_r8_r9():
    """docs/isolation.md section 2: without R8 and R9 the table leaves 16 ordered pairs
    unresolved; R8 responds to exactly the valve, line p, the position sensor and the
    n-side pressure sensor."""
    text = DOCS["isolation.md"]
    m = re.search(r"\(R6, R7\) leave (\d+) ordered pairs", text)
    sig = _design_json("pneumatic_cylinder")["signature_table"]
    faults = list(sig["R1"])
    rows = [r for r in sig if r not in ("R8", "R9")]
    unresolved = [(a, b) for a in faults for b in faults if a != b and
                  not any(sig[r][a] and not sig[r][b] for r in rows)]
    assert len(unresolved) == int(m.group(1)), unresolved
    assert {f for f in faults if sig["R8"][f]} == {
        "valve", "leak_p", "blockage_p", "position_sensor", "pressure_sensor_n"}


def test_discover_window_lengths():
    """docs/discover.md: modulating windows of '50 ms at the rig's 1 kHz, 5 s for the
    three tanks sampled at 0.1 s', smoothing over half a window."""
    import numpy as np

    from fdigen.discover.windows import discover_windows
    from fdigen.model.model_file import load_model

    m = re.search(r"(\d+) ms at the rig's 1 kHz, (\d+) s for the three tanks sampled at "
                  r"([\d.]+) s", DOCS["discover.md"])
    rig_ms, tank_s, tank_dt = int(m.group(1)), int(m.group(2)), float(m.group(3))
    w, s = discover_windows(load_model(), np.arange(2000) * 1e-3)
    assert (w, s) == (rig_ms / 1000, rig_ms / 2000)
    w, s = discover_windows(load_model("three_tank"), np.arange(2000) * tank_dt)
    assert (w, s) == (tank_s, tank_s / 2)


def _same_to_digits(shown, value, where):
    """``value`` rounds to ``shown`` (numbers to the significant digits written)."""
    if isinstance(shown, dict):
        for k, v in shown.items():
            _same_to_digits(v, value[k], f"{where}.{k}")
    elif isinstance(shown, list):
        for k, v in enumerate(shown):
            _same_to_digits(v, value[k], f"{where}[{k}]")
    elif isinstance(shown, str):
        assert shown == value, where
    else:
        mantissa = re.sub(r"e.*|\.", "", repr(float(shown))).strip("0")
        digits = len(mantissa) or 1
        assert value == pytest.approx(shown, rel=0.6 * 10.0 ** (1 - digits)), where


def test_discover_rig_table(tmp_path):
    """docs/discover.md's table of `fdigen discover` on the rig's discrepancy logs: effect,
    equation, estimates (to the digits shown) and the logs' truths."""
    rows = _table(DOCS["discover.md"], "| log | found | estimate (truth) |")
    assert rows
    for log, found, estimates, _errors in rows:
        path = RIG / "logs" / f"{log}.csv"
        if not path.is_file():
            pytest.skip(f"rig log {path} not available")
        result = CliRunner().invoke(cli_main, ["discover", str(path), "--no-build",
                                               "--no-fdi", "--json", "--out",
                                               str(tmp_path / log)])
        assert result.exit_code == 0, result.output
        got = json.loads(result.output)
        if found == "no effect":
            assert not got["effects"], (log, got["effects"])
        else:
            effect, equation = re.fullmatch(r"(\w+) in `(\w+)`", found).groups()
            assert got["effects"] == [effect] and got["equation"] == equation, log
        truth = json.loads(path.with_suffix(".json").read_text())["truth"]
        for name, value, unc, said_truth in re.findall(
                r"(\w+) ([\d.e-]+)(?: \+- ([\d.e-]+))?(?: N)? \(([\d.e-]+)\)", estimates):
            _same_to_digits(float(value), got["parameters"][name], f"{log}.{name}")
            if unc:
                assert got["uncertainty"][name] == pytest.approx(float(unc), rel=0.1), \
                    (log, name)
            assert float(said_truth) == pytest.approx(truth[name], rel=0.01), (log, name)


def test_extended_precision_bits():
    """README and docs/reproducibility.md: the refinement runs 'in 200-bit arithmetic'
    ('in 200 bits'), stopping below `2^-176` and zeroing below `2^-100` (PREC - 24, PREC/2
    in derive/riccati.py)."""
    from fdigen.derive import precise

    assert re.search(r"in\s+200-bit arithmetic \(mpmath\)", README)
    doc = DOCS["reproducibility.md"]
    assert precise.PREC == 200 and "in 200 bits until a step changes `P` by less than" in doc
    source = (PKG / "derive" / "riccati.py").read_text()
    assert "precise.PREC - 24" in source and "precise.PREC // 2" in source
    assert f"`2^-{precise.PREC - 24}` of its size" in doc
    assert doc.count(f"`2^-{precise.PREC // 2}`") == 2


@pytest.mark.parametrize("model", ["three_tank", "heat_exchanger"])
def test_models_doc_model_values(model):
    """docs/models.md's `name = value unit` of each model, its sample time, window and
    sensor noise are the model file's."""
    spec = tomllib.loads((PKG / "models" / f"{model}.toml").read_text())
    section = _section(DOCS["models.md"], model).split("\n| ")[0]  # the prose
    values = {k: v["value"] for k, v in spec["parameters"].items()}
    for ctl in spec["simulation"].get("controllers", {}).values():
        values.update({k: ctl[k] for k in ("kp", "ki") if k in ctl})
    named = re.findall(r"`(\w+) = ([\d.e+-]+)(?: [^`±]*)?`", section.replace("\n", " "))
    assert named
    for name, value in named:
        assert values[name] == pytest.approx(float(value)), (model, name)
    m = re.search(r"Sample\s+time ([\d.]+) s,\s+(?:RMS\s+)?window (\d+) samples \(([\d.]+) s\)",
                  section)
    dt, window, seconds = float(m.group(1)), int(m.group(2)), float(m.group(3))
    assert (spec["fdi"]["sample_time"], spec["fdi"]["window"]) == (dt, window)
    assert window * dt == pytest.approx(seconds)
    noise = re.search(r"\(noise ([\d.]+) (mm|K)\)", section)
    scale = 1e-3 if noise.group(2) == "mm" else 1.0
    for output in spec["outputs"].values():
        assert output["noise_std"] == pytest.approx(float(noise.group(1)) * scale)


def test_security_doc_names():
    """docs/security.md: the jinja filters `comment_text` and `c_string` of
    `fdigen.backends.escape` are registered; `.fdigen-stamp` is a JSON manifest (inputs
    hash, model name, SHA-256 of every file) and lists exactly the committed files."""
    import hashlib

    from fdigen.backends import escape
    from fdigen.backends.render import environment

    doc = DOCS["security.md"]
    assert "`comment_text` and `c_string` (`fdigen.backends.escape`)" in doc
    filters = environment().filters
    assert filters["comment_text"] is escape.comment_text
    assert filters["c_string"] is escape.c_string
    for folder in sorted(p for p in (ROOT / "generated").iterdir() if p.is_dir()):
        stamp = json.loads((folder / ".fdigen-stamp").read_text())
        assert stamp["model"] == folder.name and re.fullmatch(r"[0-9a-f]{64}", stamp["input"])
        files = {p.relative_to(folder).as_posix() for p in folder.rglob("*")
                 if p.is_file() and p.name != ".fdigen-stamp"}
        assert set(stamp["files"]) == files, folder.name
        for name, digest in stamp["files"].items():
            assert hashlib.sha256((folder / name).read_bytes()).hexdigest() == digest, name


def test_readme_lists_every_document():
    """README's Documents paragraph names every docs/*.md (and what generates the
    generated ones)."""
    for doc in sorted((ROOT / "docs").glob("*.md")):
        assert f"docs/{doc.name}" in README, doc.name
    assert "`docs/reliability.md` (generated by `scripts/reliability_report.py`" in README
    assert "`EXPERIMENTS.md` (generated by `fdigen experiments`)" in README


def test_build_never_imports_python_control():
    """README: the gains python-control's `dlqe` computes, 'without importing
    python-control' (it is for the tests' cross-checks only)."""
    assert "without\nimporting python-control" in README or \
        "without importing python-control" in README
    assert "control" not in _imports(PKG)


@pytest.mark.parametrize("doc", ["README.md", *DOCS])
def test_named_module_functions_exist(doc):
    """`module.function` names of fdigen's own modules (`precise.zoh`,
    `observers.residual_noise_level`...) exist."""
    import importlib

    text = README if doc == "README.md" else DOCS[doc]
    modules = {p.stem: p for p in PKG.rglob("*.py") if p.stem != "__init__"}
    for short, attr in sorted(set(re.findall(r"`([a-z_]+)\.([a-z_]+)`", text))):
        if short not in modules or attr in ("py", "toml", "md", "json", "csv"):
            continue
        dotted = ".".join(modules[short].relative_to(PKG.parent).with_suffix("").parts)
        assert hasattr(importlib.import_module(dotted), attr), f"{doc}: {short}.{attr}"


def test_fault_terms_defaults(tmp_path):
    """README: with `terms`, `location` may be left out (plant when a term targets a
    state) and `mode` defaults to `additive`; a list as `target` is refused pointing to
    `terms`."""
    from fdigen.errors import ModelFileError
    from fdigen.model.model_file import builtin_model_path, load_model

    text = builtin_model_path("three_tank").read_text()
    old = 'class = "clogging"\nmode = "multiplicative"\n'
    assert old in text
    path = tmp_path / "t.toml"
    path.write_text(text.replace(old, 'class = "clogging"\n'))
    clog = next(f for f in load_model(str(path)).faults if f.name == "clog12")
    assert (clog.location, clog.mode) == ("plant", "additive")
    path.write_text(text.replace(old, 'class = "clogging"\ntarget = ["h1", "h2"]\n'
                                 'term = "clog12"\n').replace(
        'terms = [{ target = "h1", term = "clog12*q12/A" }, '
        '{ target = "h2", term = "-clog12*q12/A" }]\n', ""))
    with pytest.raises(ModelFileError, match="terms"):
        load_model(str(path))


@pytest.mark.parametrize("model,pair,cls", [("three_tank", ("leak1", "pump1"), "tank1_outflow"),
                                            ("heat_exchanger", ("heater", "insulation"),
                                             "hot_loop")])
def test_models_doc_inseparable_pairs(model, pair, cls):
    """docs/models.md: leak1/pump1 (three tanks) and heater/insulation (heat exchanger)
    are structurally inseparable both ways and share one class."""
    assert f"`{pair[0]}/{pair[1]}`" in DOCS["models.md"] or cls == "hot_loop"
    iso = _design_json(model)["isolability"]
    pairs = {tuple(p) for p in iso["achievable_non_isolable"]}
    assert {pair, pair[::-1]} <= pairs
    from fdigen.model.model_file import load_model

    classes = {f.name: f.fault_class for f in load_model(model).faults}
    assert classes[pair[0]] == classes[pair[1]] == cls


def test_generated_preambles():
    """README: every generated file 'starts with a preamble: generated by fdigen, from which
    model file and template, the model hash, do not edit' (design.json carries the hash)."""
    from fdigen import __version__

    for folder in sorted(p for p in (ROOT / "generated").iterdir() if p.is_dir()):
        digest = _design_json(folder.name)["model_hash"]
        for path in sorted(p for p in folder.rglob("*") if p.is_file()):
            if path.name in ("design.json", ".fdigen-stamp"):
                continue
            head = path.read_text().splitlines()[:5]
            assert f"Generated by fdigen {__version__} -- DO NOT EDIT." in head[0], path
            assert f"model: {folder.name} (from {folder.name}.toml)" in head[1], path
            assert re.search(r"template: [\w/.]+\.j2$", head[2]), path
            assert head[3].endswith(f"model hash: {digest}"), path
