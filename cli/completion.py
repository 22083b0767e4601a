"""``starterbus completion bash|zsh|fish``: a completion script for the shell.

The script completes the command names itself; every later word it asks of ``starterbus __complete``
(:mod:`starterbus.cli.completion_words`): options, fixed choices, installed models, the fleet's device names
and the parameter keys of the model in question, or file names. That helper opens no device.
"""

from __future__ import annotations

import argparse

from starterbus.cli.arguments import json_flag
from starterbus.cli.parser import build_parser


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser], wants: str) -> None:
    p = sub.add_parser(
        "completion",
        help="print a shell completion script (bash, zsh, fish)",
        description="Print a completion script: commands, options, models, fleet device names and parameter keys "
        "(asked of `starterbus __complete` as you type); the examples install it.",
    )
    p.add_argument("shell", choices=["bash", "zsh", "fish"])
    json_flag(p)
    p.set_defaults(handler=cmd_completion)


def command_names() -> list[str]:
    return sorted(_subparsers(build_parser([])))


def command_parser(name: str) -> argparse.ArgumentParser | None:
    """The parser of command ``name`` with its options (built only for the command asked for), or None."""
    return _subparsers(build_parser([name])).get(name)


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
    names = " ".join(command_names())
    if shell == "bash":
        return f"""_starterbus() {{
    local cur=${{COMP_WORDS[COMP_CWORD]}} word files=0
    if [ "$COMP_CWORD" -eq 1 ]; then COMPREPLY=($(compgen -W "{names} --help --version" -- "$cur")); return; fi
    local IFS=$'\\n'
    COMPREPLY=()
    for word in $(starterbus __complete --bash "${{COMP_LINE:0:COMP_POINT}}" "$cur" 2>/dev/null); do
        if [ "$word" = ":files" ]; then files=1; else COMPREPLY+=("$word"); fi
    done
    if [ "$files" -eq 1 ] || [ ${{#COMPREPLY[@]}} -eq 0 ]; then COMPREPLY+=($(compgen -f -- "$cur")); fi
    if [ ${{#COMPREPLY[@]}} -eq 1 ] && [[ "${{COMPREPLY[0]}}" == *= ]]; then compopt -o nospace 2>/dev/null; fi
}}
complete -F _starterbus starterbus"""
    if shell == "zsh":
        return f"""#compdef starterbus
if (( CURRENT == 2 )); then
  compadd -- {names} --help --version
  return
fi
local -a found
local word files=0
for word in "${{(@f)$(starterbus __complete -- "${{(@)words[2,CURRENT]}}" 2>/dev/null)}}"; do
  if [[ $word == :files ]]; then files=1; elif [[ -n $word ]]; then found+=("$word"); fi
done
compadd -S '' -- ${{(M)found:#*=}}
compadd -- ${{found:#*=}}
if (( files || ${{#found}} == 0 )); then _files; fi"""
    return f"""function __starterbus_complete
    set -l words (commandline -opc) (commandline -ct)
    set -l found (starterbus __complete -- $words[2..-1] 2>/dev/null)
    for word in $found
        test "$word" != ":files"; and echo $word
    end
    if contains -- :files $found; or test (count $found) -eq 0
        __fish_complete_path (commandline -ct)
    end
end
complete -c starterbus -f
complete -c starterbus -n '__fish_use_subcommand' -a '{names}'
complete -c starterbus -n 'not __fish_use_subcommand' -a '(__starterbus_complete)'"""
