from services.level_server.main import main

raise SystemExit(main())
