"""`python -m worker`: a Celery worker process with fringelab's tasks."""

import sys

from worker.app import main

sys.exit(main())
