from services.monitoring.main import SERVICE

raise SystemExit(SERVICE.main())
