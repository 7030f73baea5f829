"""``lidar3d completion``: print the bash or zsh completion script (library twin:
:func:`lidar3d.cli.completion.bash_script`)."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "completion",
        help="print the shell completion script for bash or zsh",
        description="Print a completion script for SHELL: subcommands, options, values and files complete on Tab.",
        epilog=(
            "install:\n"
            "  bash: lidar3d completion bash > ~/.local/share/bash-completion/completions/lidar3d\n"
            '        (or: eval "$(lidar3d completion bash)" in ~/.bashrc)\n'
            "  zsh:  lidar3d completion zsh > ~/.zsh/lidar3d-completion.zsh\n"
            "        and 'source ~/.zsh/lidar3d-completion.zsh' in ~/.zshrc, after compinit\n"
            "Regenerate after upgrading lidar3d (the script lists the options of this version)."
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("shell", choices=("bash", "zsh"), metavar="SHELL", help="bash or zsh")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from lidar3d import __version__
    from lidar3d.cli.completion import bash_script, zsh_script
    from lidar3d.cli.main import build_parser

    make = bash_script if args.shell == "bash" else zsh_script
    print(make(build_parser(), __version__), end="")
    return 0
