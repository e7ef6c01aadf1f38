from metafovea.cli import main

raise SystemExit(main())
