"""One Prefect task module per stage: thin adapters store -> dsnet_core -> store."""
