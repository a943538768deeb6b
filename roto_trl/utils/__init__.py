"""Small helpers every room may use: the resolver for ``assets/`` and ``conf/``, ``key=value``
command lines, video files. They import nothing else of the package."""
