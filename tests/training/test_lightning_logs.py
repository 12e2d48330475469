"""Lightning imported after the root logger is set up (as the commands do, under Hydra) logs each line once."""

import logging

import lightning  # noqa: F401  (gives the `lightning` logger its console handler)

from ushape.training.lightning_logs import LIGHTNING_LOGGERS, log_lightning_once


class Collect(logging.Handler):
    def __init__(self):
        super().__init__()
        self.messages = []

    def emit(self, record):
        self.messages.append(record.getMessage())


def test_a_lightning_line_reaches_the_root_handlers_once_and_no_lightning_console(capsys):
    loggers = [logging.getLogger(name) for name in LIGHTNING_LOGGERS]
    saved = [(logger, list(logger.handlers), logger.propagate) for logger in loggers]
    root, collect = logging.getLogger(), Collect()
    root.addHandler(collect)
    loggers[0].addHandler(logging.StreamHandler())  # as `import lightning` leaves it
    try:
        log_lightning_once()
        logging.getLogger("lightning.pytorch.utilities.rank_zero").info("Using bfloat16 AMP")
        assert collect.messages == ["Using bfloat16 AMP"]
        assert "Using bfloat16 AMP" not in capsys.readouterr().err
        assert not any(type(h) is logging.StreamHandler for logger in loggers for h in logger.handlers)
    finally:
        root.removeHandler(collect)
        for logger, handlers, propagate in saved:
            logger.handlers[:] = handlers
            logger.propagate = propagate
