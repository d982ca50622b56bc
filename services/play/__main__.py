"""`python -m services.play serve|export ...` (the same as `cec play ...`)."""

from services.play.main import SERVICE

raise SystemExit(SERVICE.main())
