"""`bench regress`: the command line of the CI regression gate (parsing, the printed verdict and exit codes).

What the gate does — pairing, the rule, alpha spent over looks, the outputs — is `bench.api.gate`'s (`api.regress`);
the command line is checked by `bench.cli.regress_args`.
"""

from __future__ import annotations

from bench.api.gate import regress, regress_budget
from bench.cli.regress_args import help_text, parse_args
from bench.core.errors import NothingMeasured


def main(argv: list[str]) -> int:
    if argv and argv[0] in ("-h", "--help"):
        print(help_text(), end="")
        return 0
    if not argv:
        print(help_text(), end="")
        return 2
    cfg, forwarded, _ = parse_args(argv)
    if cfg.plan:
        text = regress_budget(cfg, forwarded)
        if cfg.candidate or cfg.baseline:
            print("plan=true runs nothing: candidate= and baseline= are not used")
        print(text, end="")
        return 0
    verdict = regress(cfg, forwarded)
    if verdict.nothing_measured:
        raise NothingMeasured(f"regress {verdict.gate_id}: {verdict.nothing_measured}")
    return verdict.exit_code
