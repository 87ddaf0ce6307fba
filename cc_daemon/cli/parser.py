"""The command line's parser: argparse, with a hint where a word is almost right.

`cc-daemon simulate` is the commonest slip (the option is `--simulate`); argparse
alone answers with the list of every command. The hint keeps argparse's own
line and exit status 2, and adds what was meant.
"""

from __future__ import annotations

import argparse
from typing import NoReturn

# A word typed as a command that is really an option of the daemon's.
OPTIONS_TYPED_AS_COMMANDS = {"simulate": "--simulate", "version": "--version"}


class HintingParser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        for word, option in OPTIONS_TYPED_AS_COMMANDS.items():
            if f"invalid choice: '{word}'" in message:
                message = f"{message}\n(did you mean: {self.prog} {option}?)"
        super().error(message)
