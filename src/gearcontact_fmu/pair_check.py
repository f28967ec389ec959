# placeholder: replaced by the pairlib branch
def pair_problems(params):
    return []
