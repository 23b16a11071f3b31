"""Why QuaternionCcf keeps its per-sample state as a plain tuple in CcfState's order, not a CcfState: the cost of
unpacking and building the 23-field state per sample, as a tuple and as the NamedTuple (interleaved, best of 7).

Usage: python benchmarks/state_tuple.py
"""

from __future__ import annotations

import timeit

from ccf_ros.core.ccf import CcfState


def main() -> None:
    names = CcfState._fields
    state = CcfState()
    plain = tuple(state)
    new = tuple.__new__
    env = {'S': CcfState, 's': state, 't': plain, 'new': new}
    args = ', '.join(names)
    setup = '; '.join(f'{n} = {v!r}' for n, v in zip(names, plain, strict=True))
    cases = [
        ('unpack a tuple', f'{args} = t'),
        ('unpack a CcfState', f'{args} = s'),
        ('build a tuple', f'x = ({args})'),
        ('build a CcfState: tuple.__new__', f'x = new(S, ({args}))'),
        ('build a CcfState: CcfState(...)', f'x = S({args})'),
    ]
    best = {label: float('inf') for label, _ in cases}
    n = 100000
    for _ in range(7):
        for label, stmt in cases:
            best[label] = min(best[label], timeit.timeit(stmt, setup, globals=env, number=n) / n * 1e9)
    for label, _ in cases:
        print(f'{label:35s} {best[label]:7.1f} ns')
    extra = (best['unpack a CcfState'] + best['build a CcfState: tuple.__new__']
             - best['unpack a tuple'] - best['build a tuple'])
    ratio = best['unpack a CcfState'] / best['unpack a tuple']
    print(f'unpack CcfState / tuple = {ratio:.2f}; per sample (one unpack, one build) a CcfState costs {extra:+.0f} ns')


if __name__ == '__main__':
    main()
