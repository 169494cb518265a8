"""One orchestration module per job kind: what a job of that kind loads, which science stages it runs, what it
writes. Composed from `fringelab.science` stages, `fringelab.formats` files and `fringelab.core` records; run by
the thin tasks in `worker.tasks` through `worker.runner`."""
