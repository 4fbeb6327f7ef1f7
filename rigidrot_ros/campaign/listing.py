"""The ``estimators:`` list of a campaign spec: several estimators on the same runs.

Imports nothing of the campaign (:mod:`rigidrot_ros.campaign.spec` calls it with its own
one-estimator check and error class), so spec and the several-estimator code
(:mod:`rigidrot_ros.campaign.multi`) stay free of an import circle.
"""

__all__ = ['check_estimators']


def check_estimators(items, check_one, error):
    """Validate an ``estimators:`` list with ``check_one`` (the one-estimator check).

    Each entry is an estimator mapping plus an optional ``label`` (default: its index);
    labels are unique. Returns the normalised entries, each with its ``label``; a bad
    entry raises ``error`` (one line, naming the entry).
    """
    if not isinstance(items, list) or not items:
        raise error(f'estimators must be a non-empty list of estimator mappings, got '
                    f'{items!r}')
    out, seen = [], set()
    for i, item in enumerate(items):
        if not isinstance(item, dict):
            raise error(f'estimators[{i}] must be a mapping, got {item!r}')
        item = dict(item)
        label = item.pop('label', str(i))
        if not isinstance(label, (str, int)) or isinstance(label, bool) or not str(label):
            raise error(f'estimators[{i}].label must be a non-empty string, got {label!r}')
        label = str(label)
        if label in seen:
            raise error(f'estimators[{i}].label {label!r} is used twice')
        seen.add(label)
        try:
            est = check_one(item)
        except error as exc:
            raise error(f'estimators[{i}] ({label}): {exc}') from None
        est['label'] = label
        out.append(est)
    return out
