/* fw's statechart semantics in Promela: the chart-independent half of the model
   `fw verify --spin` checks (framework/verify/promela.py writes the other half).

   A second semantics, written from docs/statecharts.md ("Semantics") and the chart
   model, not from fw's interpreter: the chart is tables (states in document
   preorder, so a state's descendants are the ids up to end_[state]; transitions
   grouped by source in priority then document order; timer slots; configure
   requests), walked by the inlines below. The exporter defines N, T, S, TAGS,
   QMAX, K, MAXC, CH, DONE_BIT and FAILED_BIT, then this file's declarations, then
   the chart's own code at the marker (variables, event fields, the property's
   monitor: observe_enter/exit/event/request and judge, eval_guard, run_actions,
   request, timeout_event, after_event, clear_fields), then the rest of this file,
   then the environment's proctype, which calls run_chart() once per step.

   SPIN bounds a d_step to 2048 jumps, so run_chart() runs a step in stages of one
   d_step each; the proctype makes the whole step atomic. */
#define COMPOUND 1
#define PARALLEL 2
#define FINAL 3
#define JUNCTION 4
#define S_EVENT 1
#define S_FIRE 2
#define S_COMPLETE 3
#define S_TIMER 4
#define S_DONE 5
/* the chart's tables: constant, so hidden from the state vector */
hidden short parent_[N]; hidden byte kind_[N]; hidden short end_[N];
hidden short tfirst_[N]; hidden short tlast_[N]; hidden short init_[N]; hidden short cfg_[N];
hidden short entry_[N]; hidden short exit_[N]; hidden short do_[N];
hidden short tsrc_[T]; hidden short ttgt_[T]; hidden int tev_[T]; hidden byte ttype_[T];
hidden byte telse_[T]; hidden short tguard_[T]; hidden short teff_[T];
hidden short snode_[S]; hidden short strans_[S]; hidden short slen_[S]; hidden int tagsym_[TAGS];
/* the chart's state */
bit act[N]; bit pend[N]; bit tm_on[S]; short tm_rem[S]; short tm_seq[S]; short seqc;
byte ptag[TAGS]; byte outq[QMAX]; byte nout; bit overflow; bit finished; bit beyond; short mon;
/* one step's scratch: cleared at the end of every step */
bit exited[N]; bit want[N]; bit dflt[N]; bit cmp[N]; bit blk[N]; short rank[S];
short chn[CH * MAXC]; byte chl[CH]; byte nch; short tmpc[MAXC]; byte tmplen;
int ev; int evbit; bit noev; bit noev_x; bit viol; bit answered; bit gok; bit found;
byte stage; byte then; bit started;
short inp; short rq; short tg; short src; short tgt; short dom; short d_; short lc; short best; short bseq;
short s_n; short s_t; short j_node; short j_b; short j_pick; short fb; short f_i; short f_m; short f_last;
short x_n; short x_k; short e_n; short e_k; short e_m; short i_tg; short i_b; short i_pick; short r_i; short r_j; short r_k;
/* == the chart's own variables and code are generated here == */
inline try_enable() {
  /* t in s_t: its guard, then through junctions: branches in order, `else` as
     the fallback; tmplen 0: not enabled */
  eval_guard(tguard_[s_t]);
  if :: gok ->
    tmplen = 1; tmpc[0] = s_t; j_node = ttgt_[s_t];
    do :: j_node != -1 && kind_[j_node] == JUNCTION && tmplen > 0 ->
         fb = -1; j_pick = -1; j_b = tfirst_[j_node];
         do :: j_b < tlast_[j_node] ->
              if :: telse_[j_b] -> if :: fb == -1 -> fb = j_b :: else -> skip fi
                 :: else -> eval_guard(tguard_[j_b]); if :: gok -> j_pick = j_b; break :: else -> skip fi
              fi; j_b++
         :: else -> break od;
         if :: j_pick == -1 -> j_pick = fb :: else -> skip fi;
         if :: j_pick == -1 || tmplen >= MAXC -> tmplen = 0
            :: else -> tmpc[tmplen] = j_pick; tmplen++; j_node = ttgt_[j_pick] fi
    :: else -> break od
  :: else -> tmplen = 0 fi
}
inline push_chain() {
  chl[nch] = tmplen; f_m = 0;
  do :: f_m < tmplen -> chn[nch * MAXC + f_m] = tmpc[f_m]; f_m++ :: else -> break od;
  nch++; f_m = 0
}
inline select_event() {
  /* outer-first: a state's own transitions (priority, document order), else its
     active children's; regions of a parallel state each in document order */
  nch = 0; s_n = 0;
  do :: s_n < N ->
       if :: act[s_n] && (s_n == 0 || !blk[parent_[s_n]]) ->
            found = 0; s_t = tfirst_[s_n];
            do :: s_t < tlast_[s_n] && !found ->
                 if :: ttype_[s_t] == 0 && (tev_[s_t] & evbit) != 0 ->
                      try_enable(); if :: tmplen > 0 -> found = 1; push_chain() :: else -> skip fi
                 :: else -> skip fi; s_t++
            :: else -> break od;
            blk[s_n] = found
       :: else -> blk[s_n] = 1 fi; s_n++
  :: else -> break od;
  s_n = 0; do :: s_n < N -> blk[s_n] = 0; s_n++ :: else -> break od; s_n = 0; s_t = 0
}
inline completeness() {
  /* complete: no awaited configuration, and a final child (compound) or
     every region complete (parallel); children first, in reverse preorder */
  s_n = N - 1;
  do :: s_n >= 0 -> cmp[s_n] = (kind_[s_n] != COMPOUND); s_n-- :: else -> break od;
  s_n = N - 1;
  do :: s_n >= 0 ->
       cmp[s_n] = cmp[s_n] && !pend[s_n];
       if :: s_n > 0 && kind_[parent_[s_n]] == PARALLEL && kind_[s_n] != JUNCTION && !cmp[s_n] -> cmp[parent_[s_n]] = 0
          :: s_n > 0 && kind_[parent_[s_n]] == COMPOUND && kind_[s_n] == FINAL && act[s_n] -> cmp[parent_[s_n]] = 1
          :: else -> skip fi;
       s_n--
  :: else -> break od; s_n = 0
}
inline select_completion() {
  completeness();
  nch = 0; s_n = 0;
  do :: s_n < N ->
       if :: act[s_n] && (s_n == 0 || !blk[parent_[s_n]]) ->
            found = 0; s_t = tfirst_[s_n];
            do :: s_t < tlast_[s_n] && !found && cmp[s_n] ->
                 if :: ttype_[s_t] == 1 ->
                      try_enable(); if :: tmplen > 0 -> found = 1; push_chain() :: else -> skip fi
                 :: else -> skip fi; s_t++
            :: else -> break od;
            blk[s_n] = found
       :: else -> blk[s_n] = 1 fi; s_n++
  :: else -> break od;
  s_n = 0; do :: s_n < N -> blk[s_n] = 0; cmp[s_n] = 0; s_n++ :: else -> break od; s_n = 0; s_t = 0
}
inline exit_one() {
  if :: exit_[x_n] != 0 -> noev_x = noev; noev = 1; run_actions(exit_[x_n]); noev = noev_x :: else -> skip fi;
  act[x_n] = 0; exited[x_n] = 1; pend[x_n] = 0;
  x_k = 0; do :: x_k < S -> if :: snode_[x_k] == x_n -> tm_on[x_k] = 0; tm_rem[x_k] = 0; tm_seq[x_k] = 0 :: else -> skip fi; x_k++ :: else -> break od;
  observe_exit()
}
inline exit_below() {
  /* every active state below dom, innermost first (reverse document preorder) */
  x_n = end_[dom]; do :: x_n > dom -> if :: act[x_n] -> exit_one() :: else -> skip fi; x_n-- :: else -> break od; x_n = 0
}
inline enter_one() {
  act[e_n] = 1;
  run_actions(entry_[e_n]);
  e_k = 0; do :: e_k < S -> if :: snode_[e_k] == e_n && strans_[e_k] != -1 -> tm_on[e_k] = 1; tm_rem[e_k] = slen_[e_k]; seqc++; tm_seq[e_k] = seqc :: else -> skip fi; e_k++ :: else -> break od;
  if :: cfg_[e_n] != -1 ->
       pend[e_n] = 1;
       e_k = 0; do :: e_k < S -> if :: snode_[e_k] == e_n && strans_[e_k] == -1 -> tm_on[e_k] = 1; tm_rem[e_k] = slen_[e_k]; seqc++; tm_seq[e_k] = seqc :: else -> skip fi; e_k++ :: else -> break od;
       rq = cfg_[e_n]; request()
  :: else -> run_actions(do_[e_n]) fi;
  observe_enter();
  if :: kind_[e_n] == FINAL && parent_[e_n] == 0 -> finished = 1 :: else -> skip fi; e_k = 0
}
inline resolve_initial() {
  /* e_n's initial state, through its initial junction: the first branch in order
     whose guard is true or absent (`else` where it stands), else its last */
  i_tg = init_[e_n];
  if :: kind_[i_tg] == JUNCTION ->
       i_pick = -1; i_b = tfirst_[i_tg];
       do :: i_b < tlast_[i_tg] -> eval_guard(tguard_[i_b]); if :: gok -> i_pick = i_b; break :: else -> skip fi; i_b++
       :: else -> break od;
       if :: i_pick == -1 -> i_pick = tlast_[i_tg] - 1 :: else -> skip fi;
       run_actions(teff_[i_pick]); i_tg = ttgt_[i_pick]
  :: else -> skip fi;
  d_ = i_tg; do :: d_ != e_n -> want[d_] = 1; d_ = parent_[d_] :: else -> break od; dflt[i_tg] = 1;
  i_tg = 0; i_b = 0; i_pick = 0
}
inline open_below() {
  /* what entering e_n means for its children: every region of a parallel state,
     the initial state of a compound one entered by default */
  if :: kind_[e_n] == PARALLEL ->
       e_m = e_n + 1;
       do :: e_m <= end_[e_n] -> if :: parent_[e_m] == e_n && !want[e_m] -> want[e_m] = 1; dflt[e_m] = 1 :: else -> skip fi; e_m++
       :: else -> break od; e_m = 0
  :: kind_[e_n] == COMPOUND && dflt[e_n] && init_[e_n] != -1 -> resolve_initial()
  :: else -> skip fi
}
inline enter_sweep() {
  /* enter the marked states below dom, outermost first, in document order */
  e_n = dom + 1;
  do :: e_n <= end_[dom] ->
       if :: want[e_n] -> enter_one(); open_below() :: else -> skip fi;
       want[e_n] = 0; dflt[e_n] = 0; e_n++
  :: else -> break od; e_n = 0
}
inline fire_chain() {
  /* chain f_i: exit below its domain, run every effect, enter the target */
  f_last = chn[f_i * MAXC + chl[f_i] - 1]; tgt = ttgt_[f_last];
  if :: tgt != -1 ->
       if :: kind_[src] == COMPOUND && src < tgt && tgt <= end_[src] -> dom = src
          :: else -> dom = parent_[src];
             do :: !(dom < tgt && tgt <= end_[dom]) -> dom = parent_[dom] :: else -> break od
       fi;
       do :: kind_[dom] == PARALLEL -> dom = parent_[dom] :: else -> break od;
       exit_below()
  :: else -> skip fi;
  f_m = 0; do :: f_m < chl[f_i] -> run_actions(teff_[chn[f_i * MAXC + f_m]]); f_m++ :: else -> break od;
  if :: tgt != -1 ->
       d_ = tgt; do :: d_ != dom -> want[d_] = 1; d_ = parent_[d_] :: else -> break od; dflt[tgt] = 1;
       enter_sweep()
  :: else -> skip fi; f_m = 0
}
inline fire_all() {
  /* fire the chosen chains in order; one whose source was left in this step does not */
  f_i = 0;
  do :: f_i < nch ->
       src = tsrc_[chn[f_i * MAXC]];
       if :: act[src] && !exited[src] -> fire_chain() :: else -> skip fi; f_i++
  :: else -> break od;
  f_i = 0; do :: f_i < N -> exited[f_i] = 0; f_i++ :: else -> break od;
  f_i = 0; do :: f_i < CH -> chl[f_i] = 0; f_i++ :: else -> break od;
  f_i = 0; do :: f_i < CH * MAXC -> chn[f_i] = 0; f_i++ :: else -> break od;
  f_i = 0; nch = 0; src = 0; tgt = 0; dom = 0; f_last = 0; d_ = 0
}
inline settle() {
  /* a configuration answer clears the requests awaiting its tag */
  tg = -1; s_n = 0;
  do :: s_n < TAGS -> if :: h_tag && tagsym_[s_n] == f_tag -> tg = s_n :: else -> skip fi; s_n++ :: else -> break od;
  if :: tg != -1 && ptag[tg] > 0 -> ptag[tg]-- :: else -> skip fi;
  s_n = 0;
  do :: s_n < N ->
       if :: tg != -1 && pend[s_n] && cfg_[s_n] == tg -> pend[s_n] = 0;
            if :: evbit == DONE_BIT -> run_actions(do_[s_n]) :: else -> skip fi
       :: else -> skip fi; s_n++
  :: else -> break od; s_n = 0; tg = 0
}
inline next_timer() {
  /* the next due timer, in deadline then creation order; none: the tick is over */
  best = -1; bseq = 32000; r_i = 0;
  do :: r_i < S -> if :: tm_on[r_i] && tm_rem[r_i] == 0 && tm_seq[r_i] < bseq -> best = r_i; bseq = tm_seq[r_i] :: else -> skip fi; r_i++ :: else -> break od;
  r_i = 0;
  if :: best == -1 -> stage = S_DONE
  :: else ->
     tm_on[best] = 0; tm_seq[best] = 0; then = S_TIMER; lc = 0;
     if :: strans_[best] == -1 ->
          if :: pend[snode_[best]] -> pend[snode_[best]] = 0;
               timeout_event();
               stage = S_EVENT
          :: else -> skip fi
     :: else ->
          after_event();
          s_t = strans_[best]; try_enable(); s_t = 0; nch = 0;
          if :: tmplen > 0 -> push_chain() :: else -> skip fi;
          stage = S_FIRE
     fi
  fi
}
inline end_step() {
  /* the bound on unanswered requests, then the property, then a canonical state */
  if :: nout > K || overflow -> beyond = 1
  :: else ->
       judge();
       assert(!viol)
  fi;
  ev = 0; evbit = 0; noev = 0; noev_x = 0; answered = 0; gok = 0; found = 0;
  inp = 0; rq = 0; best = 0; bseq = 0; tmplen = 0; j_node = 0; j_b = 0; j_pick = 0; fb = 0;
  stage = 0; then = 0; lc = 0;
  r_i = 0; do :: r_i < MAXC -> tmpc[r_i] = 0; r_i++ :: else -> break od;
  clear_fields();
  r_i = 0; seqc = 0;
  do :: r_i < S ->
       if :: tm_on[r_i] -> r_k = 1; r_j = 0;
            do :: r_j < S -> if :: tm_on[r_j] && tm_seq[r_j] < tm_seq[r_i] -> r_k++ :: else -> skip fi; r_j++ :: else -> break od;
            rank[r_i] = r_k; seqc++
       :: else -> rank[r_i] = 0 fi; r_i++
  :: else -> break od;
  r_i = 0; do :: r_i < S -> tm_seq[r_i] = rank[r_i]; rank[r_i] = 0; r_i++ :: else -> break od;
  r_i = 0; r_j = 0; r_k = 0
}
inline run_chart() {
  /* the chart until quiet (Interpreter._process, _process_timer, _complete), one
     stage per d_step (SPIN bounds a d_step's size); the whole step is atomic */
  do
  :: stage == S_EVENT -> d_step {
       noev = 0; lc = 0; observe_event();
       if :: finished -> stage = then
          :: else -> if :: evbit == DONE_BIT || evbit == FAILED_BIT -> settle() :: else -> skip fi;
             select_event(); stage = S_FIRE
       fi }
  :: stage == S_FIRE -> d_step { fire_all(); stage = S_COMPLETE }
  :: stage == S_COMPLETE -> d_step {
       noev = 1;
       if :: finished || lc >= 10000 -> noev = 0; stage = then
          :: else -> select_completion();
             if :: nch == 0 -> noev = 0; stage = then
                :: else -> lc++; stage = S_FIRE fi
       fi }
  :: stage == S_TIMER -> d_step { noev = 0; next_timer() }
  :: stage == S_DONE -> break
  od
}
