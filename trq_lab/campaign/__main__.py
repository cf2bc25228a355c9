"""python -m trq_lab.campaign: the same as trq-campaign."""

from trq_lab.campaign.cli import main

raise SystemExit(main())
