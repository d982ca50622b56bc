from services.level_server.main import SERVICE

raise SystemExit(SERVICE.main())
