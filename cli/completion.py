"""``starterbus completion bash|zsh|fish``: a completion script for the shell, generated from the parser."""

from __future__ import annotations

import argparse


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser], wants: str) -> None:
    from starterbus.cli.main import _json_flag

    p = sub.add_parser(
        "completion",
        help="print a shell completion script (bash, zsh, fish)",
        description="Print a completion script for commands and options; the examples install it.",
    )
    p.add_argument("shell", choices=["bash", "zsh", "fish"])
    _json_flag(p)
    p.set_defaults(handler=cmd_completion)


def commands() -> dict[str, list[str]]:
    """Command -> its long options, read from the real parser."""
    from starterbus.cli.main import build_parser

    out: dict[str, list[str]] = {}
    for name in _subparsers(build_parser([])):
        sub = _subparsers(build_parser([name]))[name]  # a command's options are built only when it is asked for
        out[name] = sorted(o for a in sub._actions for o in a.option_strings if o.startswith("--"))
    return out


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def cmd_completion(args: argparse.Namespace) -> int:
    text = script(args.shell)
    if args.json:
        from starterbus.cli.output import emit_json

        emit_json({"shell": args.shell, "script": text})
    else:
        print(text)
    return 0


def script(shell: str) -> str:
    """The completion script for ``shell`` (bash, zsh or fish)."""
    table = commands()
    names = " ".join(sorted(table))
    if shell == "bash":
        cases = "\n".join(f'        {c}) opts="{" ".join(o)}" ;;' for c, o in sorted(table.items()))
        return f"""_starterbus() {{
    local cur=${{COMP_WORDS[COMP_CWORD]}} cmd=${{COMP_WORDS[1]}} opts=""
    if [ "$COMP_CWORD" -eq 1 ]; then COMPREPLY=($(compgen -W "{names} --help --version" -- "$cur")); return; fi
    case "$cmd" in
{cases}
    esac
    if [[ "$cur" == -* ]]; then COMPREPLY=($(compgen -W "$opts" -- "$cur"))
    else COMPREPLY=($(compgen -f -- "$cur")); fi
}}
complete -F _starterbus starterbus"""
    if shell == "zsh":
        cases = "\n".join(f'    {c}) _arguments {" ".join(repr(o) for o in opts)} "*:file:_files" ;;'
                          for c, opts in sorted(table.items()))  # fmt: skip
        return f"""#compdef starterbus
if (( CURRENT == 2 )); then
  compadd {names}
else
  case $words[2] in
{cases}
  esac
fi"""
    lines = [f"complete -c starterbus -n '__fish_use_subcommand' -a '{names}'"]
    for c, opts in sorted(table.items()):
        lines += [f"complete -c starterbus -n '__fish_seen_subcommand_from {c}' -l {o[2:]}" for o in opts]
    return "\n".join(lines)
