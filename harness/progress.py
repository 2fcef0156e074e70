"""Progress of long work: a tqdm bar on a terminal, one plain line per finished item otherwise
(CONTRACT: "Long work shows a progress bar on a terminal and stays quiet (one line per item) when
not a TTY"). Everything goes to stderr so stdout stays clean for results."""

from __future__ import annotations

import sys


class Progress:
    """A tqdm bar on a terminal; one line per finished item otherwise."""

    def __init__(self, total: int, enabled: bool | None, desc: str) -> None:
        self.tty = sys.stderr.isatty() if enabled is None else enabled
        self.total, self.done, self.desc = total, 0, desc
        self.bar = None
        if self.tty:
            from tqdm import tqdm

            self.bar = tqdm(total=total, desc=desc, unit="step", file=sys.stderr, leave=True)

    def item(self, text: str) -> None:
        self.done += 1
        if self.bar is not None:
            self.bar.set_postfix_str(text[:60])
            self.bar.update(1)
        else:
            print(f"[{self.done}/{self.total}] {text}", file=sys.stderr, flush=True)

    def note(self, text: str) -> None:
        if self.bar is not None:
            self.bar.write(text, file=sys.stderr)
        else:
            print(text, file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
