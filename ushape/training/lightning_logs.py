"""Lightning's log lines, printed once.

`import lightning` gives the `lightning` logger a console handler of its own, and its subpackages turn off
propagation to the root logger only when the root has no handler yet. The commands import Lightning lazily,
after Hydra has set up the root logger (console and the run's log file), so each Lightning line would reach
the console twice: through Lightning's handler and through Hydra's. `log_lightning_once` leaves it to the
root logger's handlers, which also keeps Lightning's lines in the run's log file.
"""

from __future__ import annotations

import logging

LIGHTNING_LOGGERS = ("lightning", "lightning.pytorch", "lightning.fabric")


def log_lightning_once() -> None:
    """Once Lightning is imported under a configured root logger: drop Lightning's own console handlers."""
    if not logging.getLogger().handlers:
        return  # nothing else prints: Lightning's own handlers are the only ones
    for name in LIGHTNING_LOGGERS:
        logger = logging.getLogger(name)
        for handler in list(logger.handlers):
            if type(handler) is logging.StreamHandler:  # Lightning's console handler (not a file handler)
                logger.removeHandler(handler)
        logger.propagate = True
