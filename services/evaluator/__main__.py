from services.evaluator.main import SERVICE

raise SystemExit(SERVICE.main())
