"""``python -m pipeline stage=NAME key=value ...`` (Hydra; ``-m`` for sweeps)."""

from __future__ import annotations

import sys

import hydra
from rich.console import Console

from pipeline.configs import register_configs

register_configs()

#: Exit codes: bad input (config values, stores) and an interrupted run.
BAD_INPUT, FAILED, INTERRUPTED = 2, 1, 130


@hydra.main(config_path="../conf", config_name="config", version_base="1.3")
def main(cfg) -> None:
    from pipeline.execution import TaskFailed
    from pipeline.stages import run_pipeline
    from pipeline.store import StoreDamaged, StoreError

    console = Console(width=None if sys.stdout.isatty() else 132)
    err = Console(stderr=True)
    try:
        run_pipeline(cfg, console)
    except (StoreError, ValueError) as exc:
        err.print(f"[bold red]error:[/] {exc}", highlight=False, soft_wrap=True)
        sys.exit(BAD_INPUT)
    except StoreDamaged as exc:
        err.print(f"[bold red]damaged:[/] {exc}", highlight=False, soft_wrap=True)
        sys.exit(FAILED)
    except TaskFailed as exc:
        err.print(f"[bold red]failed:[/] {exc}", highlight=False, soft_wrap=True)
        sys.exit(FAILED)
    except KeyboardInterrupt:
        err.print("interrupted: finished blocks are saved; re-run the same command to resume")
        sys.exit(INTERRUPTED)


if __name__ == "__main__":
    main()
