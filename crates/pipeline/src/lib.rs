//! Pipeline glue: pipeline.toml, plans, running the chain over files
