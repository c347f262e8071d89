#!/usr/bin/env python3
"""Checks that the README's "Typical output" of `make demo` is still what the demo prints.

The demo is deterministic (README: "the same at every run"), so its typical output can be checked
instead of copied by hand and left to drift. This runs the demo's two offline steps exactly as
scripts/demo.sh does (pcr_pro_merge of agent_b into agent_a with the truth; agent_c, which must be
refused) and compares them with the README block's sections of the same name:

- every README line that is not `...` must match one line of the real output, in order;
- within a line, text must be equal, `...` stands for any text (the README shortens paths), and
  numbers must agree to 2 % (or 1e-6), so that a README from another build of the same code
  still passes while a changed estimate, anchor pair or message does not.

The ROS sections of the block (demo.launch on the two bags) are not run here: the rostests
merge_from_bag and merge_from_lsd_bag check the node on the same bags.

Usage: check_readme_demo_output.py README.md PCR_PRO_MERGE DEMO_WORLD
  (e.g. README.md build/devel/lib/pcr_pro/pcr_pro_merge build/sim/demo)
Exit: 0 current, 1 stale (each mismatch printed), 2 bad usage or a missing file.
"""
import os
import re
import subprocess
import sys
import tempfile

NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?")
REL_TOL, ABS_TOL = 0.02, 1e-6


def readme_block(path):
    """The sections (title -> lines) of the first code block after 'Typical output'."""
    with open(path, encoding="utf-8") as f:
        text = f.read()
    start = text.find("Typical output")
    if start < 0:
        raise ValueError(f"{path}: no 'Typical output' paragraph")
    fence = text.find("```", start)
    end = text.find("```", fence + 3)
    if fence < 0 or end < 0:
        raise ValueError(f"{path}: no code block after 'Typical output'")
    sections, title = {}, None
    for line in text[fence + 3:end].splitlines():
        # A section starts at each "== " title; "== exit status N" belongs to the section above.
        if line.startswith("== ") and not line.startswith("== exit status"):
            title = line
            sections[title] = []
        elif title is not None and line.strip():
            sections[title].append(line)
    return sections


def split(line):
    """(text parts, numbers) of a line: len(parts) == len(numbers) + 1."""
    parts, numbers, pos = [], [], 0
    for m in NUMBER.finditer(line):
        parts.append(line[pos:m.start()])
        numbers.append(float(m.group()))
        pos = m.end()
    parts.append(line[pos:])
    return parts, numbers


def text_matches(expected, actual):
    """Equal text, where '...' in the README stands for any text."""
    pattern = ".*".join(re.escape(piece) for piece in expected.split("..."))
    return re.fullmatch(pattern, actual) is not None


def line_matches(expected, actual):
    e_parts, e_numbers = split(expected)
    if "..." in expected:
        # A shortened line (a path): only its text is compared, numbers in the path included.
        return text_matches(expected, actual)
    a_parts, a_numbers = split(actual)
    if len(e_numbers) != len(a_numbers) or e_parts != a_parts:
        return False
    return all(abs(e - a) <= REL_TOL * max(abs(e), abs(a)) + ABS_TOL for e, a in zip(e_numbers, a_numbers))


def compare(title, expected, actual):
    """Each expected line (but '...') matched in order in `actual`. @return mismatch messages"""
    errors, pos = [], 0
    for line in expected:
        if line.strip() == "...":
            continue
        found = next((i for i in range(pos, len(actual)) if line_matches(line, actual[i])), None)
        if found is None:
            same_key = [a for a in actual if split(a)[0][0] == split(line)[0][0]]
            errors.append(f"{title}\n  README:  {line}\n  printed: {same_key[0] if same_key else '(no such line)'}")
        else:
            pos = found + 1
    return errors


def run(cmd):
    r = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, check=False)
    return r.returncode, r.stdout.splitlines()


def main(argv):
    if len(argv) != 4:
        print("usage: check_readme_demo_output.py README.md PCR_PRO_MERGE DEMO_WORLD", file=sys.stderr)
        return 2
    readme, tool = argv[1], argv[2]
    world = os.path.abspath(argv[3])  # absolute, as demo.sh gives it
    config = os.path.join(os.path.dirname(os.path.abspath(readme)), "config", "merge.yaml")
    for path in (readme, tool, world, config):
        if not os.path.exists(path):
            print(f"check_readme_demo_output: {path}: not found (build first)", file=sys.stderr)
            return 2
    try:
        sections = readme_block(readme)
    except ValueError as e:
        print(f"check_readme_demo_output: {e}", file=sys.stderr)
        return 2
    merge_title = next((t for t in sections if t.startswith("== pcr_pro_merge:")), None)
    apart_title = next((t for t in sections if t.startswith("== agent_c into agent_a")), None)
    if merge_title is None or apart_title is None:
        print(f"check_readme_demo_output: {readme}: the typical output has no pcr_pro_merge or agent_c section",
              file=sys.stderr)
        return 2
    errors = []
    with tempfile.TemporaryDirectory() as out:
        status, merged = run([tool, "--source", os.path.join(world, "agent_b"), "--target",
                              os.path.join(world, "agent_a"), "--config", config, "--truth",
                              os.path.join(world, "truth.yaml"), "--output", out])
        if status != 0:
            errors.append(f"{merge_title}: pcr_pro_merge exited {status}")
        errors += compare(merge_title, sections[merge_title], merged)
        status, apart = run([tool, "--source", os.path.join(world, "agent_c"), "--target",
                             os.path.join(world, "agent_a")])
        # demo.sh prints the first two lines and then the exit status.
        errors += compare(apart_title, sections[apart_title], apart[:2] + [f"== exit status {status}"])
    if errors:
        print(f"{readme}: the demo's typical output is stale; update it from `make demo`:")
        print("\n".join(errors))
        return 1
    print(f"{readme}: the demo's typical output matches what pcr_pro_merge prints")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
