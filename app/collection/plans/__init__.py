"""Plan files: the schema and kinds they share (``schema``), the collection plan (``collection``), the dual plan
(``dual``), the reader of both (``reader``), pose planning (``poses``), the session plan and the designed plan."""
