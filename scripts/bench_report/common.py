"""Helpers every section uses: loading result files, formatting numbers, Markdown tables, plot
links, and prose() for the blocks of the templates in templates/ (see templates/README.md)."""
import json
import os
import re
import string


def load(path):
    if not os.path.exists(path):
        return None
    with open(path) as f:
        return json.load(f)


def g(v, digits=3):
    """A number with `digits` significant digits, or '-'."""
    if v is None:
        return "-"
    if isinstance(v, str):
        return v
    if v == 0:
        return "0"
    return "%.*g" % (digits, v)


def mib(b):
    return "%.1f" % (b / 2**20)


def ordered_unique(values):
    out = []
    for v in values:
        if v not in out:
            out.append(v)
    return out


def table(header, rows, align=None):
    align = align or ["---"] + ["---:"] * (len(header) - 1)
    out = ["| " + " | ".join(header) + " |", "|" + "|".join(align) + "|"]
    for r in rows:
        out.append("| " + " | ".join(str(c) for c in r) + " |")
    return "\n".join(out) + "\n"


def img(md_dir, img_dir, name, alt):
    path = os.path.join(img_dir, name)
    if not os.path.exists(path):
        return "*(plot %s missing: run scripts/plot)*\n" % name
    return "![%s](%s)\n" % (alt, os.path.relpath(path, md_dir))


def rel_to_suite(path, suite):
    """A scene path relative to the (first) suite file's folder, as the suite lists it."""
    first = suite.split(",")[0] if suite else ""
    if not path or not first:
        return path or "-"
    return os.path.relpath(path, os.path.dirname(os.path.abspath(first)))


# The prose of the page: templates/<section>.md, split into blocks by marker lines.
TEMPLATES = os.path.join(os.path.dirname(os.path.abspath(__file__)), "templates")
BLOCK_MARK = re.compile(r"^<!-- block: ([A-Za-z0-9_-]+) -->$")
_blocks = {}


class TemplateError(Exception):
    pass


def blocks(section):
    """The blocks of templates/<section>.md by name: a block is the lines after its marker line
    up to the next marker (or the end of the file), blank lines included, less the newline that
    ends its last line (that newline belongs to the marker), so a block ending in a placeholder
    line adds nothing after what the code fills in. Text before the first marker is a comment
    for the reader and is not used."""
    if section not in _blocks:
        path = os.path.join(TEMPLATES, section + ".md")
        try:
            with open(path) as f:
                lines = f.read().splitlines(keepends=True)
        except OSError as e:
            raise TemplateError("cannot read the template %s (%s); it holds the prose of the %s "
                                "section" % (path, e.strerror, section))
        found, name = {}, None
        for n, line in enumerate(lines, 1):
            m = BLOCK_MARK.match(line.rstrip("\n"))
            if m:
                name = m.group(1)
                if name in found:
                    raise TemplateError("%s:%d: block '%s' is defined twice; rename one"
                                        % (path, n, name))
                found[name] = []
            elif name is not None:
                found[name].append(line)
        texts = {}
        for k, v in found.items():
            text = "".join(v)
            texts[k] = text[:-1] if text.endswith("\n") else text
        _blocks[section] = (path, texts)
    return _blocks[section]


def prose(section, block, **fields):
    """Block `block` of templates/<section>.md with its $placeholders filled from `fields`
    (string.Template: $name or ${name}, $$ for a dollar sign). The placeholders must be exactly
    the fields the code fills, so a misspelt one or a dropped figure is an error, not a page
    with a hole in it."""
    path, found = blocks(section)
    if block not in found:
        raise TemplateError("%s: no block '%s' (a line '<!-- block: %s -->'); the code needs it"
                            % (path, block, block))
    t = string.Template(found[block])
    where = "%s, block '%s'" % (path, block)
    if not t.is_valid():
        raise TemplateError("%s: a '$' that starts no placeholder; write $$ for a dollar sign"
                            % where)
    used = set(t.get_identifiers())
    unknown = sorted(used - set(fields))
    unused = sorted(set(fields) - used)
    if unknown or unused:
        raise TemplateError("%s: %s%s; the code fills: %s" % (
            where, "unknown placeholder(s) %s" % ", ".join("$" + x for x in unknown)
            if unknown else "",
            ("; " if unknown and unused else "") +
            ("placeholder(s) %s missing" % ", ".join("$" + x for x in unused) if unused else ""),
            ", ".join("$" + x for x in sorted(fields)) or "nothing"))
    return t.substitute(fields)
