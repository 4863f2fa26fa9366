"""MkDocs hooks: the reference pages and the Benchmarks page are generated from the code, and the
docstrings' cross-references are checked.

- ``<!-- generated: cli -->`` in a page becomes the reference of every ``excite`` command, read
  from the Typer app (its click commands: usage, help, arguments and options).
- ``<!-- generated: http -->`` becomes the HTTP API, read from the service's OpenAPI document.
- ``<!-- generated: rig-file -->`` becomes the rig file's keys, read from the pydantic models of
  the rig and of every registered measurement kind.
- ``<!-- generated: benchmarks -->`` becomes the current figure of every benchmark, read from
  ``benchmarks/results/*.json`` (written by ``benchmarks/results.py``).
- Every Sphinx-style role in a docstring of ``excite`` or ``api`` (``:class:`~excite.x.Y```,
  ``:func:`.name```, ``:mod:``, ``:meth:``, ``:attr:``, ``:data:``, ``:exc:``) must name
  something that exists: a name that does not is a warning, so ``mkdocs build --strict`` fails.
  In the rendered Python reference such a role is shown as the code it names.
"""

from __future__ import annotations

import html
import json
import logging
import re
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

log = logging.getLogger("mkdocs.hooks.excite")

ROLE = re.compile(r":(mod|class|func|meth|attr|data|exc|obj):`(~?)([^`]+)`")
MARKER = re.compile(r"<!--\s*generated:\s*([a-z-]+)\s*-->")


# --- docstring cross-references ----------------------------------------------------------------


def _objects(obj: Any):
    yield obj
    for member in obj.members.values():
        if member.is_alias:
            continue
        yield from _objects(member)


def _exists(path: str, packages: dict[str, Any]) -> bool:
    head, _, rest = path.partition(".")
    obj = packages.get(head)
    if obj is None:
        return False
    for part in rest.split(".") if rest else []:
        try:
            obj = obj.members[part]
        except (KeyError, AttributeError):
            return False
        if obj.is_alias:
            try:
                obj = obj.final_target
            except Exception:  # an alias of something outside the packages (numpy, …): it exists
                return True
    return True


def _resolves(target: str, where: Any, packages: dict[str, Any], paths: set[str]) -> bool:
    """Sphinx's Python-domain lookup, leniently: absolute, relative to the current class, module
    and its packages, a leading-dot name relative to the current package, or a dotted suffix of
    any object's path."""
    target = target.strip().removesuffix("()")
    if target.split(".")[0] not in packages and not target.startswith("."):
        scopes = []
        obj = where
        while obj is not None:
            scopes.append(obj.path)
            obj = obj.parent
        if any(_exists(f"{scope}.{target}", packages) for scope in scopes):
            return True
        return any(p.endswith("." + target) for p in paths)
    if target.startswith("."):
        module = where if where.is_module else where.module
        name = target.lstrip(".")
        base = module.path.split(".")
        candidates = [".".join(base[:i] + [name]) for i in range(len(base), 0, -1)]
        return any(_exists(c, packages) for c in candidates) or any(p.endswith("." + name) for p in paths)
    return _exists(target, packages)


def _external(target: str, packages: dict[str, Any]) -> bool:
    import builtins
    import importlib.util

    head = target.lstrip("~").split(".")[0]
    if target.startswith(".") or head in packages:
        return False
    if "." in target or hasattr(builtins, head):
        return True
    try:
        return importlib.util.find_spec(head) is not None
    except (ImportError, ValueError):
        return False


def check_references() -> int:
    import griffe

    packages = {name: griffe.load(name, search_paths=[str(ROOT)], resolve_aliases=True,
                                  resolve_external=False) for name in ("excite", "api")}
    objects = [o for pkg in packages.values() for o in _objects(pkg)]
    paths = {o.path for o in objects}
    bad = 0
    for obj in objects:
        if obj.docstring is None:
            continue
        for m in ROLE.finditer(obj.docstring.value):
            target = m.group(3)
            if _external(target, packages):
                continue  # a builtin or another library's name (ValueError, numpy.linalg.eigh)
            if not _resolves(target, obj, packages, paths):
                bad += 1
                log.warning(f"{obj.relative_filepath}:{obj.docstring.lineno}: {obj.path} refers to "
                            f":{m.group(1)}:`{target}`, which names nothing in excite or api")
    return bad


def as_code(text: str) -> str:
    """Sphinx roles in ``text`` shown as the code they name (``:class:`~a.B``` → `B`)."""
    return ROLE.sub(lambda m: f"`{m.group(3).rsplit('.', 1)[-1] if m.group(2) else m.group(3).lstrip('.')}`", text)


class RolesToCode:
    """A griffe extension: Sphinx roles shown as the code they name (``:class:`~a.B``` → `B`)."""

    def __new__(cls, *args: Any, **kwargs: Any) -> Any:
        import griffe

        class _RolesToCode(griffe.Extension):
            def on_instance(self, *, obj: Any, **kw: Any) -> None:
                if obj.docstring is not None:
                    obj.docstring.value = as_code(obj.docstring.value)

        return _RolesToCode()


# --- the command line ------------------------------------------------------------------------


def _cli_markdown() -> str:
    import typer

    from excite.cli import app as cli

    cli.register([])  # every command's module, as `excite --help` does
    root = typer.main.get_command(cli.app)
    out: list[str] = []

    def param_rows(cmd: Any, ctx: Any) -> list[str]:
        rows = []
        for p in cmd.get_params(ctx):
            if getattr(p, "hidden", False):
                continue
            record = p.get_help_record(ctx)
            if p.param_type_name == "argument":
                name = getattr(p, "human_readable_name", None) or (p.name or "").upper()
                help_ = getattr(p, "help", None) or ""
                name = f"`{name}`"
            elif record is None:
                continue
            else:
                name, help_ = record
                name = f"`{name}`"
            rows.append(f"| {name} | {html.escape(help_ or '').replace('|', '&#124;').replace(chr(10), ' ')} |")
        return rows

    def walk(cmd: Any, path: list[str], parent_ctx: Any) -> None:
        # typer vendors its own click: use the command's own context class and duck typing
        ctx = cmd.context_class(cmd, info_name=path[-1], parent=parent_ctx)
        title = " ".join(path)
        if len(path) > 1:
            out.append(f"{'#' * min(len(path) + 1, 4)} `{title}`\n")
        help_ = (cmd.help or "").strip()
        if help_:
            out.append(as_code(help_.replace("\b\n", "")) + "\n")
        usage = " ".join(cmd.collect_usage_pieces(ctx))
        out.append(f"```text\nUsage: {title} {usage}\n```\n")
        rows = param_rows(cmd, ctx)
        if rows:
            out.append("| Argument or option | What it does |\n|---|---|\n" + "\n".join(rows) + "\n")
        if hasattr(cmd, "list_commands"):
            for name in cmd.list_commands(ctx):
                sub = cmd.get_command(ctx, name)
                if sub is not None and not getattr(sub, "hidden", False):
                    walk(sub, path + [name], ctx)

    walk(root, ["excite"], None)
    return "\n".join(out)


# --- the HTTP API ----------------------------------------------------------------------------


def _schema_name(s: dict[str, Any]) -> str:
    if "$ref" in s:
        return s["$ref"].rsplit("/", 1)[-1]
    if s.get("type") == "array":
        return f"array of {_schema_name(s.get('items', {}))}"
    if "anyOf" in s:
        return " or ".join(_schema_name(x) for x in s["anyOf"])
    return s.get("type", "object")


def _http_markdown() -> str:
    from api import Settings, create_app

    with tempfile.TemporaryDirectory() as tmp:
        spec = create_app(Settings(db_path=Path(tmp) / "jobs.sqlite3")).openapi()
    out = [f"OpenAPI {spec.get('openapi', '')}, {spec['info']['title']} {spec['info'].get('version', '')}. "
           "A running service serves the same document at `/openapi.json` and an interactive "
           "view at `/docs`.\n"]
    for path, ops in spec["paths"].items():
        for method, op in ops.items():
            if method not in ("get", "post", "put", "patch", "delete", "head"):
                continue
            out.append(f"### `{method.upper()} {path}`\n")
            if op.get("summary"):
                out.append(f"**{op['summary']}**\n")
            if op.get("description"):
                out.append(as_code(op["description"].strip()) + "\n")
            params = op.get("parameters", [])
            if params:
                out.append("| Parameter | In | Type | Required | Description |\n|---|---|---|---|---|")
                for p in params:
                    desc = (p.get("description") or p.get("schema", {}).get("description") or "").replace("\n", " ")
                    out.append(f"| `{p['name']}` | {p['in']} | {_schema_name(p.get('schema', {}))} | "
                               f"{'yes' if p.get('required') else 'no'} | {desc.replace('|', '&#124;')} |")
                out.append("")
            body = op.get("requestBody", {}).get("content", {})
            if body:
                kinds = ", ".join(f"`{media}` ({_schema_name(v.get('schema', {}))})" for media, v in body.items())
                out.append(f"Body: {kinds}\n")
            responses = op.get("responses", {})
            if responses:
                out.append("Responses: " + "; ".join(f"`{code}` {r.get('description', '')}".strip()
                                                   for code, r in responses.items()) + "\n")
    schemas = spec.get("components", {}).get("schemas", {})
    if schemas:
        out.append("## Schemas\n")
        for name, s in schemas.items():
            out.append(f"### `{name}`\n")
            if s.get("description"):
                out.append(as_code(s["description"].strip()) + "\n")
            props = s.get("properties", {})
            if props:
                req = set(s.get("required", []))
                out.append("| Field | Type | Required | Description |\n|---|---|---|---|")
                for k, v in props.items():
                    desc = (v.get("description") or "").replace("\n", " ").replace("|", "&#124;")
                    out.append(f"| `{k}` | {_schema_name(v)} | {'yes' if k in req else 'no'} | {desc} |")
                out.append("")
    return "\n".join(out)


# --- the rig file ----------------------------------------------------------------------------


def _type_of(s: dict[str, Any], defs: dict[str, Any]) -> str:
    if "$ref" in s:
        return f"[{s['$ref'].rsplit('/', 1)[-1]}](#{s['$ref'].rsplit('/', 1)[-1].lower()})"
    if "anyOf" in s:
        return " or ".join(_type_of(x, defs) for x in s["anyOf"] if x.get("type") != "null") + \
            (" (optional)" if any(x.get("type") == "null" for x in s["anyOf"]) else "")
    if s.get("type") == "array":
        inner = _type_of(s.get("items", {}), defs) if s.get("items") else "any"
        return f"list of {inner}"
    if "enum" in s:
        return " \\| ".join(f"`{v}`" for v in s["enum"])
    if "const" in s:
        return f"`{s['const']}`"
    t = s.get("type", "any")
    bounds = [f"{op} {s[k]}" for k, op in (("exclusiveMinimum", ">"), ("minimum", "≥"),
                                           ("exclusiveMaximum", "<"), ("maximum", "≤")) if k in s]
    return t + (f" ({', '.join(bounds)})" if bounds else "")


def _model_table(name: str, s: dict[str, Any], defs: dict[str, Any]) -> list[str]:
    out = [f"### {name}\n"]
    if s.get("description"):
        out.append(as_code(" ".join(s["description"].split())) + "\n")
    props = s.get("properties", {})
    if props:
        req = set(s.get("required", []))
        out.append("| Key | Type | Default | Description |\n|---|---|---|---|")
        for k, v in props.items():
            default = "required" if k in req else (f"`{json.dumps(v['default'])}`" if "default" in v and
                                                   len(json.dumps(v["default"])) < 40 else "")
            desc = " ".join((v.get("description") or "").split()).replace("|", "&#124;")
            out.append(f"| `{k}` | {_type_of(v, defs)} | {default} | {desc} |")
        out.append("")
    return out


def _rig_markdown() -> str:
    from excite.factors import base as registry
    from excite.rig.config import RigConfig

    schema = RigConfig.model_json_schema()
    defs = dict(schema.get("$defs", {}))
    out = _model_table("The rig", schema, defs)
    sections, sensors = [], []
    for kind in registry.kinds():
        if kind.config is None:
            continue
        s = kind.config.model_json_schema()
        defs.update(s.pop("$defs", {}))
        if kind.section:
            sections.append((f"`{kind.section}:` ({kind.name})", s))
        for k in kind.sensor_kinds:
            sensors.append((f"`kind: {k}`", s))
    if sections:
        out.append("## Sections read by a measurement kind\n")
        for title, s in sections:
            out += _model_table(title, s, defs)
    out.append("## Sensors (`sensors:` entries, by `kind`)\n")
    for title, s in sensors:
        out += _model_table(title, s, defs)
    out.append("## Nested objects\n")
    for name in sorted(defs):
        out += _model_table(name, defs[name], defs)
    return "\n".join(out)


# --- benchmarks ------------------------------------------------------------------------------


def _figure(v: Any) -> str:
    if isinstance(v, dict) and {"median", "range"} <= set(v):
        lo, hi = v["range"]
        return f"{v['median']:g} (range {lo:g}–{hi:g}, {v.get('runs', '?')} runs)"
    if isinstance(v, dict):
        return "; ".join(f"{k} {_figure(x)}" for k, x in v.items())
    if isinstance(v, float):
        return f"{v:g}"
    return html.escape(json.dumps(v, ensure_ascii=False)) if not isinstance(v, str) else html.escape(v)


BENCH_SCRIPT = re.compile(r"benchmarks/(bench_[a-z0-9_]+\.py)\b")


def _benchmarks_markdown() -> str:
    import ast

    results = {}
    for f in sorted((ROOT / "benchmarks" / "results").glob("*.json")):
        d = json.loads(f.read_text())
        results.setdefault(d.get("script") or "", []).append(d)
    scripts = sorted((ROOT / "benchmarks").glob("bench_*.py"))
    recorded = {d["benchmark"]: d for ds in results.values() for d in ds}
    out = ["| Benchmark | What it measures | Current figures |", "|---|---|---|"]
    sections = []
    for script in scripts:
        doc = ast.get_docstring(ast.parse(script.read_text())) or ""
        first = " ".join(doc.split("\n\n")[0].split()).replace("|", "&#124;")
        mine = [d for d in recorded.values() if script.name in BENCH_SCRIPT.findall(d.get("command") or "")]
        link = ", ".join(f"[{d['benchmark']}](#{d['benchmark']})" for d in mine) or \
            f"not recorded yet: `python benchmarks/{script.name}`"
        out.append(f"| `{script.name}` | {first} | {link} |")
    for d in recorded.values():
        m = d.get("machine", {})
        load = d.get("load_average", {})
        sha = (d.get("commit") or {}).get("sha") or "?"
        dirty = " (with uncommitted changes)" if (d.get("commit") or {}).get("dirty") else ""
        sections.append(f"## {d['benchmark']}\n")
        if d.get("note"):
            sections.append(d["note"] + "\n")
        sections.append("| Figure | Value |\n|---|---|")
        for k, v in d.get("figures", {}).items():
            sections.append(f"| `{k}` | {_figure(v)} |")
        sections.append("")
        sections.append(f"`{d.get('command', '')}` · commit `{sha[:10]}`{dirty} · {m.get('cpu', '?')}, "
                        f"{m.get('cores', '?')} cores, {m.get('memory_gib', '?')} GiB, Python {m.get('python', '?')} · "
                        f"load average {load.get('before')} → {load.get('after')} · {d.get('finished', '')}\n")
    return "\n".join(out) + "\n\n" + "\n".join(sections)


GENERATORS = {"cli": _cli_markdown, "http": _http_markdown, "rig-file": _rig_markdown,
              "benchmarks": _benchmarks_markdown}


# --- MkDocs events ---------------------------------------------------------------------------


def on_pre_build(config: Any) -> None:
    bad = check_references()
    if bad:
        log.warning(f"{bad} docstring cross-reference(s) name nothing")


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any) -> str:
    def fill(m: re.Match) -> str:
        gen = GENERATORS.get(m.group(1))
        if gen is None:
            log.warning(f"{page.file.src_uri}: no generator named {m.group(1)!r}")
            return m.group(0)
        return gen()

    return MARKER.sub(fill, markdown)

