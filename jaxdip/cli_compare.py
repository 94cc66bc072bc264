"""``jaxdip compare A B``: the command-line side of ``jaxdip.runner.compare``.

Prints what besides the results differs (``note:`` lines: provenance, config keys), one line per statistic that
is not identical, and a summary line; exit status 0 (no significant difference), 1 (significant differences,
differences without an interval, or statistics on one side only) or 2 (the folders cannot be compared).
"""

from __future__ import annotations

from jaxdip.cli_errors import emit, error


def cmd_compare(args) -> int:
    from jaxdip.runner import compare as C

    try:
        ma, mb = C.read_metrics(args.a), C.read_metrics(args.b)
    except C.CompareError as e:
        return error(e.key, e.why)
    if ma["experiment"] != mb["experiment"]:
        return error(args.b, f"results of {mb['experiment']!r}, {args.a} of {ma['experiment']!r}: not comparable")
    for n in C.context(args.a, args.b, ma, mb):
        emit(f"note: {n}")
    sa, sb = C.per_seed_samples(args.a, ma["results"]), C.per_seed_samples(args.b, mb["results"])

    def samples(path):
        return C.sample_test(sa[path], sb[path]) if path in sa and path in sb else None

    if sa and sb:
        emit(f"note: per-seed data in both folders: {sum(p in sb for p in sa)} statistics tested on them")
    findings = C.compare(ma["results"], mb["results"], rtol=args.rtol, atol=args.atol, alpha=args.alpha,
                         samples=samples)
    for f in findings:
        if f.kind != C.IDENTICAL:
            emit(C.line(f))
    code = C.status(findings)
    emit(f"compare: {C.summary(findings)} -> {'differences' if code else 'no significant difference'} "
         f"(exit {code})")
    return code
