"""The tracker: one loop (`run`) over roles (`estimator`, `gate`, `assigner`, `management`), their
implementations, and the registry of methods composed from them (`registry`)."""
