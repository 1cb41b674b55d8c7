"""`python -m baselines.real_panda`."""

from baselines.real_panda.pipeline import main

raise SystemExit(main())
