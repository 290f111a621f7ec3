"""Progress bars: the one rule for when the package draws one."""
from __future__ import annotations

import os
import sys

from tqdm import tqdm


def progress_bar(iterable=None, enabled: bool = True, **kwargs) -> tqdm:
    """A tqdm bar over `iterable` (or one updated by hand: total=...), drawn only when `enabled`, stderr is a
    terminal and TQDM_DISABLE is unset: in a log file or a pipe every update would add a carriage-return line, and
    the loops log their own progress lines. Disabled bars still count (update, set_postfix) silently."""
    shown = enabled and sys.stderr.isatty() and not os.environ.get("TQDM_DISABLE")
    return tqdm(iterable, disable=not shown, dynamic_ncols=True, **kwargs)
